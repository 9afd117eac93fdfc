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
  column-wise relative to ``K_opt`` (the columns differ by orders of
  magnitude and in unit): ``d = ||(K_bs - K_opt) / s||_F``, ``s_j = max_i |K_opt,ij|``
  (one motor: the element-wise ``|K_opt|``).

Beyond the flexible joint (ch. 16 applies the method to "the 38 tendons"):
the antagonistic joint rig (N = 2 motors, state ``[q, qd, theta1, theta2,
omega1, omega2]``) uses the same steps at its operating point (pretension):
the torque coordinates become ``[q, qd, tau_1..N, taud_1..N]`` with
``tau_i = -P_i f_i`` the joint torque of tendon ``i`` (:func:`torque_state_map`),
Table 16.1's weights are repeated per tendon (``tau``, ``taud`` entries) and
``R = r I_N``; ``K_bs`` (N x 2 + 2N) comes from AutoDiff of the same law at the
operating point.
* :func:`monte_carlo_gains` is Algorithm 3 (best of N random draws, log-uniform
  in a box; through the sweep runner); :func:`optimize_gains` is a
  least-squares search on ``log Omega`` (scipy ``least_squares``, positivity by
  construction) started from the best of a few draws.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
from pydrake.autodiffutils import AutoDiffXd, InitializeAutoDiff, ExtractGradient

from awiwi_drake.analysis.linear import lqr
from awiwi_drake.analysis.sweep import monte_carlo_points, run_sweep
from awiwi_drake.control.backstepping import JointModel, impedance_backstepping, joint_model
from awiwi_drake.parameters.backstepping import ImpedanceBacksteppingGains, OptimalGainsCase

__all__ = ["GainFit", "rate_limited_case", "finger_optimal_gains", "torque_coordinates", "torque_state_map", "backstepping_feedback",
           "system_feedback", "optimal_feedback", "gain_distance", "monte_carlo_gains",
           "backstepping_feedback_batch", "gain_distances", "evaluate_samples", "optimize_gains", "OMEGA_NAMES"]

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


def torque_state_map(model: JointModel, state0) -> np.ndarray:
    """``T`` with ``[q, qd, tau_1..N, taud_1..N] ~= T [q, qd, theta_1..N, omega_1..N]`` at rest at ``state0``.

    ``tau_i = -P_i f(x_i)``, ``x_i = r_m theta_i + P_i q + x0_i``: ``dtau_i/dq = -P_i^2 k_i``,
    ``dtau_i/dtheta_i = -P_i k_i r_m`` (and the same for the rates). One torsion spring (P = -1,
    r_m = 1) gives :func:`torque_coordinates` with ``k = phi'``.
    """
    n_m = model.num_motors
    x = np.asarray(state0, dtype=float)
    P, rm = np.array(model.coupling, float), float(model.motor_pulley_radius)
    xs = rm * x[2:2 + n_m] + P * x[0] + np.array(model.elongation_offset, float)
    k = np.array([float(np.ravel(model.spring.stiffness(np.array([v])))[0]) for v in xs])
    if np.any(k <= 0):
        raise ValueError(f"torque_state_map: a spring is slack at the operating point (stiffness {k}); "
                         "the torque coordinates need taut tendons")
    n = 2 + 2 * n_m
    T = np.zeros((n, n))
    T[0, 0] = T[1, 1] = 1.0
    for i in range(n_m):
        T[2 + i, 0] = T[2 + n_m + i, 1] = -P[i] ** 2 * k[i]
        T[2 + i, 2 + i] = T[2 + n_m + i, 2 + n_m + i] = -P[i] * k[i] * rm
    return T


def _rig_point(rig, op=None):
    """(operating point, design model, T) of a rig for the gain fit."""
    op = rig.operating_point() if op is None else op
    model = joint_model(rig)
    return op, model, torque_state_map(model, op.state)


def backstepping_feedback(model: JointModel, gains: ImpedanceBacksteppingGains, state0=None) -> np.ndarray:
    """``K_bs = -du/dx`` (N x n, rig coordinates) of the impedance law at ``state0`` (default: rest at 0),
    by AutoDiffXd; the reference is the link angle of ``state0``."""
    omega = [[getattr(gains, name) for name in OMEGA_NAMES]]
    return backstepping_feedback_batch(model, omega, state0)[0]


def backstepping_feedback_batch(model: JointModel, omegas, state0=None) -> np.ndarray:
    """``K_bs(Omega_s)`` for many samples at once: ``(S, N, n)`` for ``omegas`` of shape ``(S, 4)``.

    One AutoDiffXd evaluation of the same law (:func:`~awiwi_drake.control.backstepping.impedance_backstepping`)
    with each gain a column of ``S`` values: numpy broadcasts the law over the samples (the law is
    element-wise in the gains), so the Python overhead of the law is paid once per batch.
    """
    om = np.asarray(omegas, dtype=float)
    if om.ndim != 2 or om.shape[1] != len(OMEGA_NAMES) or not np.all(om > 0):
        raise ValueError(f"backstepping_feedback_batch: omegas must be (samples, 4) positive "
                         f"({', '.join(OMEGA_NAMES)}), got shape {om.shape}")
    n = model.state_size
    x0 = np.zeros(n) if state0 is None else np.asarray(state0, dtype=float)
    x = InitializeAutoDiff(x0).ravel()
    ref = [AutoDiffXd(float(x0[0]))] + [AutoDiffXd(0.0)] * 4
    gains = SimpleNamespace(**{name: om[:, j:j + 1] for j, name in enumerate(OMEGA_NAMES)})
    u, _, _ = impedance_backstepping(x, ref, model, gains)
    u = np.broadcast_to(np.asarray(u, dtype=object), (om.shape[0], model.num_motors))
    return -ExtractGradient(np.ascontiguousarray(u).ravel()).reshape(om.shape[0], model.num_motors, n)


def system_feedback(controller, state0) -> np.ndarray:
    """``K = -d motor_torque / d state`` of a controller *system*, through ``ToAutoDiffXd()``."""
    ad = controller.ToAutoDiffXd()
    ctx = ad.CreateDefaultContext()
    x = InitializeAutoDiff(np.asarray(state0, dtype=float)).ravel()
    ad.GetInputPort("state").FixValue(ctx, x)
    rport = ad.GetInputPort("joint_angle_reference")
    rport.FixValue(ctx, np.array([AutoDiffXd(float(state0[0]))] + [AutoDiffXd(0.0)] * (rport.size() - 1)))
    u = ad.GetOutputPort("motor_torque").Eval(ctx)
    return -ExtractGradient(np.asarray(u, dtype=object))


def optimal_feedback(rig, case: OptimalGainsCase | None = None, op=None) -> tuple[np.ndarray, np.ndarray]:
    """``(K_opt in Table 16.1 coordinates, K_opt in rig coordinates)`` from the framework's LQR at ``op``.

    One motor: vectors (4,); N motors: (N, 2 + 2N), weights ``diag(Q11, Q22, Q33 I_N, Q44 I_N)``, ``R = r I_N``.
    """
    c = case or OptimalGainsCase()
    op, model, T = _rig_point(rig, op)
    n_m = model.num_motors
    q = np.concatenate([c.q_weights[:2], np.repeat(c.q_weights[2], n_m), np.repeat(c.q_weights[3], n_m)])
    Q = T.T @ np.diag(q) @ T
    res = lqr(rig, Q, c.r_weight * np.eye(n_m), op)
    K_rig = np.asarray(res.K).reshape(n_m, -1)
    K_tau = K_rig @ np.linalg.inv(T)
    return (K_tau.ravel(), K_rig.ravel()) if n_m == 1 else (K_tau, K_rig)


def gain_distance(feedback_tau: np.ndarray, target_tau: np.ndarray) -> float:
    """``||(K_bs - K_opt) / s||_F``, ``s_j = max_i |K_opt,ij|`` (column-wise relative; one motor: ``|K_opt|``)."""
    return float(gain_distances(np.atleast_2d(feedback_tau)[None], target_tau)[0])


def gain_distances(feedback_tau: np.ndarray, target_tau: np.ndarray) -> np.ndarray:
    """:func:`gain_distance` of each of ``S`` feedbacks ``(S, N, n)`` to one target."""
    target = np.atleast_2d(target_tau)
    scale = np.max(np.abs(target), axis=0)
    return np.sqrt(np.sum(((np.asarray(feedback_tau, float) - target) / scale) ** 2, axis=(1, 2)))


def _gains(omega) -> ImpedanceBacksteppingGains:
    return ImpedanceBacksteppingGains(**dict(zip(OMEGA_NAMES, (float(v) for v in omega))))


def _feedback_tau(model, T_inv, omega, state0=None) -> np.ndarray:
    K = backstepping_feedback(model, _gains(omega), state0).reshape(model.num_motors, -1) @ T_inv
    return K.ravel() if model.num_motors == 1 else K


def evaluate_samples(points, *, model: JointModel, T_inv: np.ndarray, target: np.ndarray, state0=None) -> list:
    """Distances of a batch of Omega samples (``points``: dicts with the :data:`OMEGA_NAMES`), one
    :func:`backstepping_feedback_batch` evaluation per batch (module-level: runs in the sweep
    runner's workers, ``run_sweep(..., batch=...)``)."""
    omegas = np.array([[p[k] for k in OMEGA_NAMES] for p in points], dtype=float)
    K = backstepping_feedback_batch(model, omegas, state0) @ T_inv
    return [float(d) for d in gain_distances(K, target)]


def _setup(rig, case, op=None):
    c = case or OptimalGainsCase()
    op, model, T = _rig_point(rig, op)
    target, _ = optimal_feedback(rig, c, op)
    return c, model, np.linalg.inv(T), target, np.asarray(op.state, float)


def rate_limited_case(case: OptimalGainsCase, link_inertia: float, rate_hz: float) -> OptimalGainsCase:
    """``case`` with the gain box's upper corner bounded by a sampled loop at ``rate_hz``.

    The design places poles at ``-K3``, ``-K4`` (the z3, z4 error dynamics) and ``-Kd,imp / m`` (the
    impedance damping): each is kept at ``|h lambda| <= 1/4`` (``K3, K4 <= f_s / 4``,
    ``Kd,imp <= m f_s / 4``).  Unbounded, the joint rig's fit asks for K3 = 2.6e4 1/s, which the
    3 kHz loop cannot realise (the command saturates 97 % of a step).
    """
    if not rate_hz > 0:
        raise ValueError(f"rate_limited_case: rate_hz = {rate_hz} must be > 0")
    hi = list(case.gain_high)
    hi[1] = min(hi[1], link_inertia * rate_hz / 4.0)
    hi[2] = min(hi[2], rate_hz / 4.0)
    hi[3] = min(hi[3], rate_hz / 4.0)
    return case.replace(gain_high=tuple(hi))


def monte_carlo_gains(rig, case: OptimalGainsCase | None = None, *, samples: int | None = None,
                      seed: int | None = None, executor=None, op=None, batch: int = 500) -> GainFit:
    """Algorithm 3: the best of ``samples`` log-uniform draws of Omega in the case's box.

    ``executor`` goes to :func:`awiwi_drake.analysis.sweep.run_sweep` (default: a process pool);
    the samples are evaluated ``batch`` at a time (:func:`evaluate_samples`).
    """
    c, model, T_inv, target, x0 = _setup(rig, case, op)
    n = int(samples if samples is not None else c.samples)
    pts = monte_carlo_points(dict(zip(OMEGA_NAMES, c.gain_low)), dict(zip(OMEGA_NAMES, c.gain_high)), n,
                             seed=c.seed if seed is None else seed, log=True)
    t0 = time.perf_counter()
    res = run_sweep(evaluate_samples, pts, executor=executor, batch=batch,
                    fixed=dict(model=model, T_inv=T_inv, target=target, state0=x0))
    d = np.array(res.values, dtype=float)
    i = int(np.argmin(d))
    omega = [pts[i][k] for k in OMEGA_NAMES]
    return GainFit(_gains(omega), _feedback_tau(model, T_inv, omega, x0), target, float(d[i]), n,
                   time.perf_counter() - t0, "monte-carlo (Algorithm 3)")


def optimize_gains(rig, case: OptimalGainsCase | None = None, *, starts: int = 8, seed: int | None = None,
                   op=None) -> GainFit:
    """Least squares on ``log Omega`` inside the case's box ``[gain_low, gain_high]`` (scipy ``least_squares``),
    from the best of ``starts`` draws, at ``op``.  A sampled loop bounds the box by its rate (see
    :class:`~awiwi_drake.parameters.backstepping.JointRigOptimalGainsCase`)."""
    from scipy.optimize import least_squares
    c, model, T_inv, target, x0 = _setup(rig, case, op)
    scale = np.max(np.abs(np.atleast_2d(target)), axis=0)
    t0 = time.perf_counter()
    lo, hi = np.log(c.gain_low), np.log(c.gain_high)
    count = [0]

    def resid(z):
        count[0] += 1
        return ((np.atleast_2d(_feedback_tau(model, T_inv, np.exp(z), x0)) - np.atleast_2d(target)) / scale).ravel()

    rng = np.random.default_rng(c.seed if seed is None else seed)
    z0s = rng.uniform(lo, hi, size=(int(starts), 4))
    best = min(z0s, key=lambda z: float(np.sum(resid(z) ** 2)))
    sol = least_squares(resid, best, method="trf", bounds=(lo, hi), x_scale=1.0, xtol=1e-12, ftol=1e-12, gtol=1e-12,
                        max_nfev=2000)
    omega = np.exp(sol.x)
    fb = _feedback_tau(model, T_inv, omega, x0)
    return GainFit(_gains(omega), fb, target, gain_distance(fb, target), count[0], time.perf_counter() - t0,
                   "least squares on log(Omega) (scipy)")


def finger_optimal_gains(finger: str, *, pretension: float = 20.0, rate_hz: float = 3000.0,
                         case=None, starts: int = 16) -> list[tuple[str, GainFit, object]]:
    """Ch. 16 gain selection for each independent DoF of a finger (the thesis: 'applied to the 19 joints').

    Each DoF ``j`` is designed as an antagonistic joint (:func:`awiwi_drake.rigs.joint_rig`) with the
    DoF's own inertia ``(S^T M S)_jj`` (finger MultibodyPlant, straight finger), an equivalent pulley
    radius ``r_eq = sqrt(sum_i (P S)_ij^2 / 2)`` (so that the pair's stiffness ``r_eq^2 (k1 + k2)``
    equals the diagonal of ``(P S)^T K_t (P S)`` at equal tendon stiffness), the finger's joint damping,
    the hand's spring law and ``pretension``; Table 16.1's weights per tendon, the gain box bounded
    by ``rate_hz`` (:func:`rate_limited_case`).  The thumb uses ``P(0)`` (its P depends on q).
    Returns ``(joint name, GainFit, JointRigParams)`` per DoF.
    """
    from awiwi_drake.hand.coupling import finger_coupling
    from awiwi_drake.hand.plant import make_finger_plant
    from awiwi_drake.parameters.backstepping import JointRigOptimalGainsCase
    from awiwi_drake.parameters.hand import finger_params
    from awiwi_drake.parameters.rigs import JointRigParams
    from awiwi_drake.rigs import joint_rig
    c = finger_coupling(finger)
    S = c.dof_selection
    PS = np.asarray(c.P(np.zeros(c.num_joints)), dtype=float) @ S
    plant, _ = make_finger_plant(finger)
    M = S.T @ plant.CalcMassMatrix(plant.CreateDefaultContext()) @ S
    fp = finger_params(finger)
    damping = float(getattr(fp, "joint_damping", 1e-5))
    names = [c.joint_names[int(np.argmax(np.abs(S[:, j])))] for j in range(S.shape[1])]
    out = []
    for j, name in enumerate(names):
        r_eq = float(np.sqrt(np.sum(PS[:, j] ** 2) / 2.0))
        p = JointRigParams(link_inertia=float(M[j, j]), link_pulley_radius=r_eq, link_damping=damping,
                           pretension=float(pretension))
        rig = joint_rig(params=p)
        cs = rate_limited_case(case or JointRigOptimalGainsCase(), p.link_inertia, rate_hz)
        out.append((name, optimize_gains(rig, cs, starts=starts), p))
    return out
