"""Optimal backstepping gains (thesis ch. 16).

The impedance backstepping law of section 15.3 is linear in the state for a
linear spring, ``u = -K_bs(Omega) x`` (16.1)-(16.3), with
``Omega = (Kp,imp, Kd,imp, K3, K4) > 0``. Chapter 16 picks ``Omega`` so that
``K_bs(Omega)`` is close to an LQR gain ``K_opt`` (16.4).

* ``K_bs(Omega)`` is *derived*, not copied: :func:`backstepping_feedback`
  differentiates the controller's law (the function the
  :class:`~awiwi_drake.control.backstepping.ImpedanceBackstepping` system
  evaluates) with AutoDiffXd at the operating point;
  :func:`system_feedback` does the same through the TemplateSystem
  (``ToAutoDiffXd``) and a test checks both agree.
* ``K_opt`` comes from the framework: :func:`awiwi_drake.analysis.linear.lqr`
  (Drake ``LinearQuadraticRegulator`` on the linearised rig). Table 16.1
  weights the state ``[q, qd, tau, taud]`` (``tau = k (theta - q)``); the
  weights are mapped to the rig state ``[q, qd, theta, thetad]`` by the
  similarity ``x_tau = T x``: ``Q_rig = T^T Q T``.
* The distance is measured on the gains in Table 16.1's coordinates,
  element-wise relative to ``|K_opt|`` (the four entries differ by orders of
  magnitude): ``d = ||(K_bs - K_opt) / |K_opt| ||_2``.
* :func:`monte_carlo_gains` is Algorithm 3 (best of N random draws, log-uniform
  in a box; through the sweep runner); :func:`optimize_gains` is a
  least-squares search on ``log Omega`` (scipy ``least_squares``, positivity by
  construction) started from the best of a few draws.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from pydrake.autodiffutils import AutoDiffXd, InitializeAutoDiff, ExtractGradient

from awiwi_drake.analysis.linear import lqr
from awiwi_drake.analysis.sweep import monte_carlo_points, run_sweep
from awiwi_drake.control.backstepping import JointModel, impedance_backstepping, joint_model
from awiwi_drake.parameters.backstepping import ImpedanceBacksteppingGains, OptimalGainsCase

__all__ = ["GainFit", "torque_coordinates", "backstepping_feedback", "system_feedback", "optimal_feedback",
           "gain_distance", "monte_carlo_gains", "optimize_gains", "OMEGA_NAMES"]

OMEGA_NAMES = ("stiffness", "damping", "k3", "k4")


@dataclass
class GainFit:
    """Result of a gain search.

    Attributes
    ----------
    gains : ImpedanceBacksteppingGains
        The selected Omega.
    feedback : ndarray (4,)
        ``K_bs(Omega)`` in Table 16.1 coordinates ``[q, qd, tau, taud]`` (``u = -K x``).
    target : ndarray (4,)
        ``K_opt`` in the same coordinates.
    distance : float
        Relative distance ``||(K_bs - K_opt)/|K_opt| ||``.
    evaluations : int
        Number of ``K_bs`` evaluations.
    wall_time : float
        Search time [s].
    method : str
    """

    gains: ImpedanceBacksteppingGains
    feedback: np.ndarray
    target: np.ndarray
    distance: float
    evaluations: int
    wall_time: float
    method: str


def torque_coordinates(stiffness: float) -> np.ndarray:
    """``T`` with ``[q, qd, tau, taud] = T [q, qd, theta, thetad]``, ``tau = k (theta - q)``."""
    k = float(stiffness)
    return np.array([[1, 0, 0, 0], [0, 1, 0, 0], [-k, 0, k, 0], [0, -k, 0, k]], dtype=float)


def _rig_stiffness(rig) -> float:
    op = rig.operating_point()
    return float(op.info.get("stiffness", rig.params.stiffness))


def backstepping_feedback(model: JointModel, gains: ImpedanceBacksteppingGains, state0=None) -> np.ndarray:
    """``K_bs = -du/dx`` (rig coordinates) of the impedance law at ``state0`` (default: rest at 0), by AutoDiffXd."""
    n = model.state_size
    x0 = np.zeros(n) if state0 is None else np.asarray(state0, dtype=float)
    x = InitializeAutoDiff(x0).ravel()
    ref = [AutoDiffXd(float(x0[0]))] + [AutoDiffXd(0.0)] * 4
    u, _, _ = impedance_backstepping(x, ref, model, gains)
    return -ExtractGradient(np.asarray(u, dtype=object))


def system_feedback(controller, state0) -> np.ndarray:
    """``K = -d motor_torque / d state`` of a controller *system*, through ``ToAutoDiffXd()``."""
    ad = controller.ToAutoDiffXd()
    ctx = ad.CreateDefaultContext()
    x = InitializeAutoDiff(np.asarray(state0, dtype=float)).ravel()
    ad.GetInputPort("state").FixValue(ctx, x)
    rport = ad.GetInputPort("link_angle_reference")
    rport.FixValue(ctx, np.array([AutoDiffXd(float(state0[0]))] + [AutoDiffXd(0.0)] * (rport.size() - 1)))
    u = ad.GetOutputPort("motor_torque").Eval(ctx)
    return -ExtractGradient(np.asarray(u, dtype=object))


def optimal_feedback(rig, case: OptimalGainsCase | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(K_opt in Table 16.1 coordinates, K_opt in rig coordinates)`` from the framework's LQR."""
    c = case or OptimalGainsCase()
    T = torque_coordinates(_rig_stiffness(rig))
    Q = T.T @ np.diag(c.q_weights) @ T
    res = lqr(rig, Q, [[c.r_weight]])
    K_rig = np.asarray(res.K).reshape(1, -1)
    return (K_rig @ np.linalg.inv(T)).ravel(), K_rig.ravel()


def gain_distance(feedback_tau: np.ndarray, target_tau: np.ndarray) -> float:
    """``||(K_bs - K_opt) / |K_opt| ||_2`` (element-wise relative)."""
    return float(np.linalg.norm((np.asarray(feedback_tau) - target_tau) / np.abs(target_tau)))


def _gains(omega) -> ImpedanceBacksteppingGains:
    return ImpedanceBacksteppingGains(**dict(zip(OMEGA_NAMES, (float(v) for v in omega))))


def _feedback_tau(model, T_inv, omega) -> np.ndarray:
    return (backstepping_feedback(model, _gains(omega)).reshape(1, -1) @ T_inv).ravel()


def evaluate_sample(*, model: JointModel, T_inv: np.ndarray, target: np.ndarray, stiffness: float,
                    damping: float, k3: float, k4: float) -> float:
    """Distance of one Omega sample (module-level: runs in the sweep runner's workers)."""
    return gain_distance(_feedback_tau(model, T_inv, (stiffness, damping, k3, k4)), target)


def _setup(rig, case):
    c = case or OptimalGainsCase()
    target, _ = optimal_feedback(rig, c)
    T_inv = np.linalg.inv(torque_coordinates(_rig_stiffness(rig)))
    return c, joint_model(rig), T_inv, target


def monte_carlo_gains(rig, case: OptimalGainsCase | None = None, *, samples: int | None = None,
                      seed: int | None = None, executor=None) -> GainFit:
    """Algorithm 3: the best of ``samples`` log-uniform draws of Omega in the case's box.

    ``executor`` goes to :func:`awiwi_drake.analysis.sweep.run_sweep` (default: a process pool).
    """
    c, model, T_inv, target = _setup(rig, case)
    n = int(samples if samples is not None else c.samples)
    pts = monte_carlo_points(dict(zip(OMEGA_NAMES, c.gain_low)), dict(zip(OMEGA_NAMES, c.gain_high)), n,
                             seed=c.seed if seed is None else seed, log=True)
    t0 = time.perf_counter()
    res = run_sweep(evaluate_sample, pts, executor=executor,
                    fixed=dict(model=model, T_inv=T_inv, target=target))
    d = np.array(res.values, dtype=float)
    i = int(np.argmin(d))
    omega = [pts[i][k] for k in OMEGA_NAMES]
    return GainFit(_gains(omega), _feedback_tau(model, T_inv, omega), target, float(d[i]), n,
                   time.perf_counter() - t0, "monte-carlo (Algorithm 3)")


def optimize_gains(rig, case: OptimalGainsCase | None = None, *, starts: int = 8, seed: int | None = None
                   ) -> GainFit:
    """Least squares on ``log Omega`` (scipy ``least_squares``), from the best of ``starts`` draws."""
    from scipy.optimize import least_squares
    c, model, T_inv, target = _setup(rig, case)
    t0 = time.perf_counter()
    lo, hi = np.log(c.gain_low), np.log(c.gain_high)
    count = [0]

    def resid(z):
        count[0] += 1
        return (_feedback_tau(model, T_inv, np.exp(z)) - target) / np.abs(target)

    rng = np.random.default_rng(c.seed if seed is None else seed)
    z0s = rng.uniform(lo, hi, size=(int(starts), 4))
    best = min(z0s, key=lambda z: float(np.sum(resid(z) ** 2)))
    sol = least_squares(resid, best, method="trf", x_scale=1.0, xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=2000)
    omega = np.exp(sol.x)
    fb = _feedback_tau(model, T_inv, omega)
    return GainFit(_gains(omega), fb, target, gain_distance(fb, target), count[0], time.perf_counter() - t0,
                   "least squares on log(Omega) (scipy)")
