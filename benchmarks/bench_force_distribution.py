"""Benchmark of the tendon force distribution (ch. 7): Algorithm 2 vs (7.6) as a Drake program.

Run from the repository root: ``PYTHONPATH=. python benchmarks/bench_force_distribution.py``.
Prints, for the index finger (constant 8 x 4 coupling, offline null space) and the thumb
(position-dependent coupling P(q) with its tension Hessian, online SVD), both with the hand's
radii and calibrated spring curve: time per call (median, p90) cold and warm-started with one
QP (the in-loop use at 3 kHz), torque error, bound violation, relative stiffness error, and
the share of requests reported infeasible.
"""

from __future__ import annotations

import time

import numpy as np

from awiwi_drake.components.tendon import joint_stiffness
from awiwi_drake.control.force_distribution import finger_force_distribution
from awiwi_drake.hand.coupling import finger_coupling


def _case(finger, rng):
    c = finger_coupling(finger)
    q = rng.uniform(-1.0, 1.0, c.num_joints) if not c.is_constant else np.zeros(c.num_joints)
    P = c.P(q)
    H = None if c.is_constant else np.stack([c.tension_hessian(q, e) for e in np.eye(c.num_tendons)])
    return q, P, H


def run(n: int = 100, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    print(f"{'case':34s} {'median us':>10s} {'p90 us':>8s} {'max |tau err| Nm':>17s} {'max viol N':>11s} "
          f"{'median K err':>12s} {'infeasible':>10s}")
    for finger in ("index", "thumb"):
        solvers = {m: finger_force_distribution(finger, method=m) for m in ("algorithm2", "optimal")}
        rows = {k: ([], [], [], [], 0) for k in ("algorithm2", "optimal", "optimal, warm 1 QP")}
        for _ in range(n):
            q, P, H = _case(finger, rng)
            m = P.shape[0]
            f_star = rng.uniform(15.0, 160.0, m)
            tau = -P.T @ f_star
            K_des = joint_stiffness(P, solvers["optimal"].stiffness_map(f_star)[0], f_star, H) * rng.uniform(0.5, 1.6)
            kw = {} if finger != "thumb" else dict(q=q)
            out = {}
            for key, call in (("algorithm2", lambda: solvers["algorithm2"].solve(tau, K_des, **kw)),
                              ("optimal", lambda: solvers["optimal"].solve(tau, K_des, **kw)),
                              ("optimal, warm 1 QP", lambda: solvers["optimal"].solve(
                                  tau, K_des, warm_start=out["optimal"].forces * (1 + 1e-3 * rng.standard_normal(m)),
                                  max_iterations=1, **kw))):
                t0 = time.perf_counter()
                res = call()
                dt = time.perf_counter() - t0
                out[key] = res
                t, te, v, ke, inf = rows[key]
                t.append(dt), te.append(res.torque_error), v.append(res.bound_violation), ke.append(res.stiffness_error)
                rows[key] = (t, te, v, ke, inf + (res.status != "ok"))
        for key, (t, te, v, ke, inf) in rows.items():
            t = np.array(t) * 1e6
            print(f"{finger + ', ' + key:34s} {np.median(t):10.0f} {np.percentile(t, 90):8.0f} {max(te):17.2e} "
                  f"{max(v):11.2e} {np.median(ke):12.4f} {inf / n:10.2%}")


if __name__ == "__main__":
    run()
