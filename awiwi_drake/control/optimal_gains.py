"""Optimal backstepping gains (thesis ch. 16).

The impedance backstepping law of section 15.3 is linear in the state for a linear spring,
``u = -K_bs(Omega) x`` (16.1)-(16.3), ``Omega = (Kp,imp, Kd,imp, K3, K4) > 0``; ch. 16 picks ``Omega`` so that
``K_bs(Omega)`` is close to an LQR gain ``K_opt`` (16.4).

* ``K_bs(Omega)`` is *derived*: :func:`backstepping_feedback` differentiates the controller's own law with
  AutoDiffXd at the operating point (:func:`system_feedback` the same through ``ToAutoDiffXd``).
* ``K_opt`` is Drake's LQR on the linearised rig (:func:`awiwi_drake.analysis.linear.lqr`); Table 16.1 weights the
  state ``[q, qd, tau, taud]``, mapped to the rig state by ``x_tau = T x``: ``Q_rig = T^T Q T``.
* The distance is column-wise relative to ``K_opt`` in Table 16.1's coordinates (the columns differ by orders of
  magnitude and in unit): ``d = ||(K_bs - K_opt) / s||_F``, ``s_j = max_i |K_opt,ij|``.

Beyond the flexible joint (ch. 16 applies the method to "the 38 tendons"): on the antagonistic joint rig the torque
coordinates are ``[q, qd, tau_1..N, taud_1..N]`` (``tau_i = -P_i f_i``, :func:`torque_state_map`), Table 16.1's
weights repeated per tendon, ``R = r I_N``.  On a finger or the hand (:func:`select_finger_force_gains`, registered
``optimal-backstepping``) only "the two lower levels" ``(K3, K4)`` of the 15.5 law are selected per DoF.
:func:`monte_carlo_gains` is Algorithm 3 (best of N log-uniform draws in a box, through the sweep runner);
:func:`optimize_gains` a least-squares search on ``log Omega`` from the best of a few draws.
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

__all__ = ["GainFit", "rate_limited_case", "JointForceGainFit", "FingerForceGains", "select_finger_force_gains",
           "finger_optimal_backstepping_controller", "torque_state_map", "backstepping_feedback",
           "system_feedback", "optimal_feedback", "gain_distance", "monte_carlo_gains",
           "backstepping_feedback_batch", "gain_distances", "evaluate_samples", "optimize_gains", "OMEGA_NAMES"]

OMEGA_NAMES = ("stiffness", "damping", "k3", "k4")


@dataclass
class GainFit:
    """Result of a gain search."""

    gains: ImpedanceBacksteppingGains  # the selected Omega
    feedback: np.ndarray              # K_bs(Omega) in Table 16.1 coordinates [q, qd, tau, taud] (u = -K x)
    target: np.ndarray                # K_opt in the same coordinates
    distance: float                   # (16.4), gain_distance
    evaluations: int                  # K_bs evaluations
    wall_time: float                  # [s]
    method: str


def torque_state_map(model: JointModel, state0) -> np.ndarray:
    """``T`` with ``[q, qd, tau_1..N, taud_1..N] ~= T [q, qd, theta_1..N, omega_1..N]`` at rest at ``state0``.

    ``tau_i = -P_i f(x_i)``, ``x_i = r_m theta_i + P_i q + x0_i``: ``dtau_i/dq = -P_i^2 k_i``,
    ``dtau_i/dtheta_i = -P_i k_i r_m`` (and the same for the rates). One torsion spring (P = -1,
    r_m = 1) gives ``tau = k (theta - q)`` with ``k = phi'``.
    """
    n_m = model.num_motors
    x = np.asarray(state0, dtype=float)
    P, rm = np.array(model.coupling, float), float(model.motor_pulley_radius)
    xs = rm * x[2:2 + n_m] + P * x[0] + np.array(model.elongation_offset, float)
    k = np.array([float(np.ravel(model.spring.stiffness(np.array([v])))[0]) for v in xs])
    return _tendon_torque_map(P, k, rm)


def _tendon_torque_map(P, k, rm: float) -> np.ndarray:
    """``T`` of :func:`torque_state_map` from the column ``P`` (N,), the spring slopes ``k`` (N,) and ``r_m``."""
    P, k = np.asarray(P, float), np.asarray(k, float)
    if np.any(k <= 0):
        raise ValueError(f"torque_state_map: a spring is slack at the operating point (stiffness {k}); "
                         "the torque coordinates need taut tendons")
    n_m = P.size
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
    """``K_bs(Omega_s)`` (S, N, n) for ``omegas`` (S, 4): one AutoDiffXd evaluation of the law
    (:func:`~awiwi_drake.control.backstepping.impedance_backstepping`) with each gain a column of ``S`` values (the law
    is element-wise in the gains, so numpy broadcasts it over the samples)."""
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

    The poles ``-K3``, ``-K4`` (the z3, z4 error dynamics) and ``-Kd,imp / m`` are kept at ``|h lambda| <= 1/4``
    (``K3, K4 <= f_s / 4``, ``Kd,imp <= m f_s / 4``); unbounded, the joint rig's fit asks for gains the 3 kHz loop
    cannot realise.
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


# ---------------------------------------------------------------------------
# Ch. 16 per DoF of a finger or the hand
# ---------------------------------------------------------------------------
@dataclass
class JointForceGainFit:
    """The ch. 16 selection of ``Omega = (K3, K4)`` for one DoF (:func:`select_finger_force_gains`).

    ``K_bs`` of the DoF's law is bilinear in the selected gains, ``K_bs = B0 + K3 B1 + K4 B2 + K3 K4 B3``
    (``basis``, torque coordinates ``[q, qd, tau_1..N, taud_1..N]``, ``u = -K x``): (15.63) is linear in
    ``K4`` and in ``K3``, with ``K3 K4`` from ``K4 z4``, ``z4 = f' - beta`` and ``beta = ... - K3 z3``.
    """

    name: str
    dof: int
    tendons: tuple                    # the DoF's tendons (indices in the rig)
    stiffness: float                  # Kp,imp of the DoF (given: the 15.5 mode design's diagonal)
    damping: float                    # Kd,imp
    k3: float
    k4: float
    box: tuple                        # (low, high) of K3 and K4 [1/s]
    r_weight: float                   # R of the target LQR
    target: np.ndarray                # K_opt (N, 2 + 2N), torque coordinates
    target_poles: np.ndarray          # eig(A - B K_opt) of the DoF's one-link model
    open_loop_poles: np.ndarray
    basis: np.ndarray                 # (4, N, 2 + 2N)
    distance: float
    evaluations: int

    def feedback(self, k3, k4) -> np.ndarray:
        """``K_bs`` for gains ``k3``, ``k4`` (scalars: (N, n); arrays of S samples: (S, N, n))."""
        a = np.asarray(k3, float)[..., None, None]
        b = np.asarray(k4, float)[..., None, None]
        B0, B1, B2, B3 = self.basis
        return B0 + a * B1 + b * B2 + a * b * B3

    def cost(self, k3, k4) -> np.ndarray:
        """(16.4): :func:`gain_distance` of ``K_bs(k3, k4)`` to the target (vectorised over samples)."""
        K = self.feedback(np.atleast_1d(k3), np.atleast_1d(k4))
        return gain_distances(K, self.target)

    def monte_carlo(self, samples: int, seed: int = 0) -> tuple[float, float, float]:
        """Algorithm 3 in the same box on the same cost: ``(best distance, K3, K4)`` of ``samples``
        log-uniform draws."""
        rng = np.random.default_rng(seed)
        lo, hi = np.log(self.box)
        z = rng.uniform(lo, hi, size=(int(samples), 2))
        d = self.cost(np.exp(z[:, 0]), np.exp(z[:, 1]))
        i = int(np.argmin(d))
        return float(d[i]), float(np.exp(z[i, 0])), float(np.exp(z[i, 1]))


@dataclass
class FingerForceGains:
    """Per-DoF selections (:class:`JointForceGainFit`) and the per-tendon gains they give the 15.5 law."""

    fits: list
    k3: np.ndarray                    # (m,) per tendon
    k4: np.ndarray
    rate_hz: float | None

    def plot(self, ax=None):
        """``(fig, axes)``: the selected ``K3``, ``K4`` per DoF against the box (left) and the distance (16.4) of
        each selection to its target (right); ``ax``: two axes."""
        from awiwi_drake.plotting import figure_axes, label_axes
        fig, axes = figure_axes(ax, ncols=2, figsize=(10, 3.5))
        x = np.arange(len(self.fits))
        names = [f.name for f in self.fits]
        axes[0].semilogy(x, [f.k3 for f in self.fits], "o", label="K3")
        axes[0].semilogy(x, [f.k4 for f in self.fits], "s", mfc="none", label="K4")
        for b in self.fits[0].box if self.fits else ():
            axes[0].axhline(b, color="0.5", ls=":", lw=1)
        axes[1].bar(x, [f.distance for f in self.fits], color="C2")
        for a in axes:
            a.set_xticks(x, names, rotation=90 if len(x) > 6 else 0)
        label_axes(axes[0], "gain [1/s]", xlabel="DoF", title="ch. 16 selection (dotted: the box)")
        label_axes(axes[1], "distance to the LQR (16.4) [-]", xlabel="DoF", legend=None)
        fig.tight_layout()
        return fig, axes

    def table(self) -> str:
        rows = [f"{'DoF':>8} {'Kp,imp':>8} {'Kd,imp':>9} {'R':>9} {'K3':>8} {'K4':>8} {'distance':>9}  box"]
        for f in self.fits:
            rows.append(f"{f.name:>8} {f.stiffness:8.4g} {f.damping:9.3g} {f.r_weight:9.3g} {f.k3:8.4g} {f.k4:8.4g} "
                        f"{f.distance:9.4g}  [{f.box[0]:g}, {f.box[1]:g}]")
        return "\n".join(rows)


def _law_feedback_basis(sub, sub_op, stiffness: float, damping: float, params, rate_hz) -> np.ndarray:
    """``(B0, B1, B2, B3)`` (rig coordinates) of the 15.5 law on the one-link subsystem ``sub``: AutoDiffXd of
    the law (:class:`~awiwi_drake.control.finger_backstepping.FingerBacksteppingLaw`, the registered
    ``backstepping``'s law) at four gain pairs; bilinear in ``(K3, K4)`` (see :class:`JointForceGainFit`)."""
    from awiwi_drake.control.finger_backstepping import FingerBacksteppingLaw
    x0 = np.asarray(sub_op.state, dtype=float)
    N = sub.coupling.num_tendons
    P = np.asarray(sub.coupling.P(np.zeros(1)), float)[:, 0]
    rm = float(sub.params.motor.pulley_radius)
    x = InitializeAutoDiff(x0).ravel()
    q, v, th, w = x[:1], x[1:2], x[2:2 + N], x[2 + N:]
    u = dict(joint_angle_reference=np.array([AutoDiffXd(0.0)]), joint_angle=q, joint_velocity=v,
             elongation=rm * th + P * q[0], motor_angle=th, motor_velocity=w)
    K = {}
    for a, b in ((1.0, 1.0), (2.0, 1.0), (1.0, 2.0), (2.0, 2.0)):
        law = FingerBacksteppingLaw(sub, params, op=sub_op, rate_hz=rate_hz, joint_gains=([[stiffness]], [[damping]]),
                                    force_gains=(a, b))
        K[a, b] = -ExtractGradient(np.asarray(law(u), dtype=object))
    B3 = K[2, 2] - K[2, 1] - K[1, 2] + K[1, 1]
    B1 = K[2, 1] - K[1, 1] - B3
    B2 = K[1, 2] - K[1, 1] - B3
    return np.stack([K[1, 1] - B1 - B2 - B3, B1, B2, B3])


def select_finger_force_gains(rig, case=None, *, params=None, rate_hz: float | None = 3000.0,
                              op=None) -> FingerForceGains:
    """Ch. 16 on every independent DoF of a finger or the hand, for the 15.5 law
    (:mod:`awiwi_drake.control.finger_backstepping`); the thesis's steps per DoF ``j``:

    1. *The model*: the DoF's one-link subsystem (:func:`~awiwi_drake.control.joint_design.joint_subsystem`),
       linearised by Drake.
    2. *State feedback* (16.1)-(16.3): ``K_bs(Omega)`` is AutoDiffXd of the registered law on that subsystem
       (``Kp,imp``, ``Kd,imp`` given: the diagonal of the law's mode design), in Table 16.1's torque coordinates.
    3. *The target* ``K_opt``: Drake's LQR with Table 16.1's ``Q`` per tendon and ``R = r I``, ``r`` the smallest
       weight whose fastest closed-loop pole is at most ``max(sampled_pole_limit * rate_hz, target_margin *
       fastest open-loop mode)`` (bisection on ``log r``).  Chosen: Table 16.1's ``R = 0.1`` is far below what the
       structure produces on a finger joint, and a free ``R`` ends in gains the 3 kHz loop cannot realise.
    4. *The selection* (16.4): least squares on ``log (K3, K4)`` in ``[gain_low, sampled_pole_limit * rate_hz]``,
       from the best of the box corners and ``starts`` draws.

    Each tendon gets the smallest ``K3`` and ``K4`` of the DoF it acts on (chosen: conservative for a shared
    tendon; the Lyapunov decrease holds for any positive gains).  ``rate_hz=None``: a continuous design (the box's
    corner 1e4 1/s).
    """
    from scipy.optimize import least_squares
    from awiwi_drake.control.chain import chain_design_point
    from awiwi_drake.control.finger_backstepping import FingerBacksteppingLaw
    from awiwi_drake.control.joint_design import joint_subsystem
    from awiwi_drake.analysis.linear import linearize
    from awiwi_drake.parameters.backstepping import FingerOptimalGainsCase
    from awiwi_drake.parameters.hand_control import HandChainParams
    c = case or FingerOptimalGainsCase()
    p = params or HandChainParams()
    op = op or rig.operating_point()
    law = FingerBacksteppingLaw(rig, p, op=op, rate_hz=rate_hz)
    point = chain_design_point(rig, op, params=p)
    PS = point.coupling_matrix
    k = PS.shape[1]
    k_max = 1e4 if rate_hz is None else p.sampled_pole_limit * float(rate_hz)   # the box's upper corner
    if not c.gain_low < k_max:
        raise ValueError(f"select_finger_force_gains: gain_low = {c.gain_low} 1/s is not below the box's upper corner "
                         f"{k_max:g} 1/s (sampled_pole_limit x rate_hz)")
    fits = []
    for j in range(k):
        sub, sub_op, _ = joint_subsystem(rig, j, point=point, params=p)
        col = PS[:, j]
        tendons = tuple(int(i) for i in np.flatnonzero(np.abs(col) > 1e-12 * np.abs(col).max()))
        N = sub.coupling.num_tendons
        if len(tendons) != N:
            raise AssertionError(f"select_finger_force_gains: DoF {j} has {len(tendons)} tendons, its subsystem {N}")
        P = np.asarray(sub.coupling.P(np.zeros(1)), float)[:, 0]
        T = _tendon_torque_map(P, sub_op.tendon_stiffness, float(sub.params.motor.pulley_radius))
        T_inv = np.linalg.inv(T)
        basis = np.einsum("snm,mk->snk", _law_feedback_basis(sub, sub_op, law.Kp[j, j], law.Kd[j, j], p, rate_hz),
                          T_inv)
        lin = linearize(sub, sub_op)
        open_poles = np.linalg.eigvals(lin.A)
        limit = max(k_max, c.target_margin * np.abs(open_poles).max())
        qw = np.concatenate([c.q_weights[:2], np.repeat(c.q_weights[2], N), np.repeat(c.q_weights[3], N)])
        Q = T.T @ np.diag(qw) @ T

        def target(log_r):
            K = np.asarray(lqr(sub, Q, 10.0 ** log_r * np.eye(N), sub_op, linearization=lin).K).reshape(N, -1)
            return K, np.linalg.eigvals(lin.A - lin.B @ K)

        lo, hi = np.log10(c.r_search)
        if np.abs(target(hi)[1]).max() > limit:
            raise ValueError(f"select_finger_force_gains: DoF {j} of {rig.name!r}: even R = {c.r_search[1]:g} gives an "
                             f"LQR faster than {limit:.4g} 1/s (FingerOptimalGainsCase.r_search)")
        if np.abs(target(lo)[1]).max() <= limit:
            hi = lo
        for _ in range(60):
            if hi - lo < 1e-3:
                break
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if np.abs(target(mid)[1]).max() <= limit else (mid, hi)
        K_opt, cl = target(hi)
        tgt = K_opt @ T_inv
        fit = JointForceGainFit(str(sub.coupling.joint_names[0]), j, tendons, float(law.Kp[j, j]), float(law.Kd[j, j]),
                                0.0, 0.0, (float(c.gain_low), float(k_max)), float(10.0 ** hi), tgt, cl, open_poles,
                                basis, np.inf, 0)
        scale = np.max(np.abs(np.atleast_2d(tgt)), axis=0)
        zlo, zhi = np.log(fit.box)

        def resid(z):
            return ((fit.feedback(np.exp(z[0]), np.exp(z[1])) - tgt) / scale).ravel()

        rng = np.random.default_rng(c.seed + j)
        z0s = [np.array([a, b]) for a in (zlo, zhi) for b in (zlo, zhi)] + list(rng.uniform(zlo, zhi, (c.starts, 2)))
        best = None
        for z0 in z0s:
            sol = least_squares(resid, z0, bounds=([zlo, zlo], [zhi, zhi]), xtol=1e-14, ftol=1e-14, gtol=1e-14,
                                max_nfev=500)
            fit.evaluations += int(sol.nfev)
            if best is None or sol.cost < best.cost:
                best = sol
        fit.k3, fit.k4 = (float(v) for v in np.exp(best.x))
        fit.distance = float(fit.cost(fit.k3, fit.k4)[0])
        fits.append(fit)
    m = PS.shape[0]
    k3, k4 = np.full(m, np.inf), np.full(m, np.inf)
    for fit in fits:
        ix = list(fit.tendons)
        k3[ix] = np.minimum(k3[ix], fit.k3)
        k4[ix] = np.minimum(k4[ix], fit.k4)
    if not np.all(np.isfinite(k3)):
        raise ValueError(f"select_finger_force_gains: tendons {np.flatnonzero(~np.isfinite(k3))} of {rig.name!r} act "
                         "on no DoF")
    return FingerForceGains(fits, k3, k4, rate_hz)


def finger_optimal_backstepping_controller(rig, case=None, *, params=None, op=None, rate_hz: float | None = 3000.0):
    """Registered ``optimal-backstepping`` for fingers and the hand: the 15.5 law
    (:func:`~awiwi_drake.control.finger_backstepping.finger_backstepping_controller`) with its force-level gains
    ``(K3, K4)`` selected per DoF by ch. 16 (:func:`select_finger_force_gains`); the selection is
    ``controller.law.design.force_gains``."""
    from awiwi_drake.control.base import StaticLawController
    from awiwi_drake.control.finger_backstepping import FingerBacksteppingLaw, check_backstepping_springs
    check_backstepping_springs(rig)
    sel = select_finger_force_gains(rig, case, params=params, rate_hz=rate_hz, op=op)
    law = FingerBacksteppingLaw(rig, params, op=op, rate_hz=rate_hz, force_gains=(sel.k3, sel.k4))
    law.name = "finger_optimal_backstepping"
    law.design.force_gains = sel
    return StaticLawController(law)
