"""Benchmark of the tendon force distribution (ch. 7, Algorithm 2): time per call, accuracy.

Run from the repository root: ``PYTHONPATH=. python benchmarks/bench_force_distribution.py``.
Prints, for the index finger (constant 8 x 4 coupling, offline null space) and a
position-dependent 4 x 2 thumb-base-like coupling (online SVD): time per call
(median over random feasible requests), torque error, bound violation, relative
stiffness error, and the share of requests reported infeasible.
"""

from __future__ import annotations

import time

import numpy as np

from awiwi_drake.control.force_distribution import (TendonForceDistribution, TendonStiffnessMap,
                                                    index_finger_coupling, joint_stiffness)

C1, C2 = 1e4, 5e6   # test spring f = c1 x + c2 x^2 (k_t = sqrt(c1^2 + 4 c2 f))


def _thumb_like(q):
    A0 = np.array([[0.01, 0.01, -0.03], [-0.01, 0.01, -0.03], [0.01, -0.01, -0.03], [-0.01, -0.01, -0.03]])
    B = np.array([[0.008, 0.008, 0.0], [-0.008, 0.008, 0.0], [0.008, -0.008, 0.0], [-0.008, -0.008, 0.0]])

    def h(qq):
        c0, s0, c1, s1 = np.cos(qq[0]), np.sin(qq[0]), np.cos(qq[1]), np.sin(qq[1])
        R = np.array([[c1, 0, s1], [0, 1, 0], [-s1, 0, c1]]) @ np.array([[1, 0, 0], [0, c0, -s0], [0, s0, c0]])
        return np.linalg.norm((R @ B.T).T - A0, axis=1)
    eps = 1e-6
    return np.stack([(h(q + eps * e) - h(q - eps * e)) / (2 * eps) for e in np.eye(2)], axis=1)


def run(n: int = 300, seed: int = 0) -> None:
    kmap = TendonStiffnessMap.from_function(lambda f: np.sqrt(C1 ** 2 + 4 * C2 * np.maximum(f, 0.0)), 0.0, 200.0)
    rng = np.random.default_rng(seed)
    P = index_finger_coupling()
    cases = [("index finger, offline W (8 x 4)", TendonForceDistribution(kmap, coupling=P), lambda: P, 8),
             ("thumb-like base, online SVD (4 x 2)", TendonForceDistribution(kmap),
              lambda: _thumb_like(rng.uniform(-1.0, 1.0, 2)), 4)]
    print(f"{'case':40s} {'median us':>10s} {'p90 us':>8s} {'max |tau err| Nm':>17s} {'max viol N':>11s} "
          f"{'median K err':>12s} {'infeasible':>10s}")
    for name, fd, getP, m in cases:
        times, terr, viol, kerr, infeasible = [], [], [], [], 0
        for _ in range(n):
            Pq = getP()
            f_star = rng.uniform(15.0, 160.0, m)
            tau = -Pq.T @ f_star
            K_des = joint_stiffness(Pq, kmap(f_star)[0], f_star) * rng.uniform(0.7, 1.3)
            t0 = time.perf_counter()
            res = fd.solve(tau, K_des, P=None if fd._offline is not None else Pq)
            times.append(time.perf_counter() - t0)
            terr.append(res.torque_error)
            viol.append(res.bound_violation)
            kerr.append(res.stiffness_error)
            infeasible += res.status != "ok"
        t = np.array(times) * 1e6
        print(f"{name:40s} {np.median(t):10.0f} {np.percentile(t, 90):8.0f} {max(terr):17.2e} {max(viol):11.2e} "
              f"{np.median(kerr):12.3f} {infeasible / n:10.2%}")


if __name__ == "__main__":
    run()
