"""Thesis ch. 5/7/8: the joint stiffness set by co-contraction, measured on the closed-loop finger.

The thesis's central claim is that the nonlinear springs make the joint stiffness (5.12)
``K_q = P^T diag(k_t(f)) P + sum_i f_i d2h_i/dq2`` a function of the tendon forces, so that
co-contraction (raising every tendon's force without moving the joint, ch. 7) stiffens the joint.
:func:`measure_joint_stiffness` measures it as a user would on the hand: the finger is closed at
3 kHz with the thesis physics on (motor friction and ripple, spring hysteresis, the guides'
friction), a small external torque is ramped onto one DoF after the other, and the static
deflections give the measured stiffness matrix ``K = L D^-1`` (column ``j`` of ``D``: every DoF's
deflection under the load ``L`` on DoF ``j``).  Which stiffness that is depends on the loop:

* ``joint-pd`` holds the **motor positions** (3 kHz motor PD, ``kp = 100 Nm/rad``): the load
  stretches the springs, so the finger shows the mechanism's (5.12) at the tendon forces it holds (on the ring and
  fifth with the PIP/DIP coupler (5.16)-(5.17) between the DoF's two plant joints),
  each tendon's spring in series with its motor servo ``kp / r_m^2`` (4e6 N/m: 0.3 %).  The two
  Dahl states of the thesis physics add their presliding stiffness in parallel for a load this
  small (their state moves far less than a presliding length): the spring hysteresis (Fig 4.8b)
  ``w_i / delta_h`` with ``w_i = beta f_i`` on each spring, and the guides' friction (4.1)
  ``W_i / delta_g`` on each tendon path, ``(P S)^T diag(W / delta_g) (P S)`` on the joints
  (:func:`~awiwi_drake.control.chain.guide_presliding_stiffness`).  Co-contraction by pretension
  (the motor angles of a higher operating point) raises all three with the forces.
* the **force chain** (``cascaded:no-observer``: joint impedance -> (7.6) distribution -> tendon force
  loops) holds the tendon *forces*: statically the springs' compliance is inside the force loop, so
  the finger shows the joint law's own ``K_imp / (1 + K_tau + K_prev)``
  (:attr:`~awiwi_drake.control.joint_design.JointDesign.static_stiffness`), plus the guides'
  presliding stiffness in parallel (the guides sit between the force sensor and the joint).
  ``HandChainParams.stiffness_scale`` (co-contraction through the distribution) raises the tendon
  forces and the (5.12) stiffness of the springs, but not this static stiffness: the force loop hides
  it below its bandwidth.  Ch. 8's correction (8.1) ``K_eff^-1 = K_imp^-1 + K_mech^-1`` is the law of
  a motor-side impedance with the springs in series (the thesis's motor controller "similar to a
  simple PD", section 8.1); in this chain (the force loop between) the effective static stiffness is
  ``K_imp``, which is why ``joint_stage_controller(stiffness_correction=...)`` keeps ``K_imp = K_eff``
  and only asks the distribution for ``K_mech = eps K_eff`` (8.2).

The default chain's (9.2) observer cancels a load below its friction bound (the guides' friction it
cannot tell from a load): it would measure no deflection, hence ``cascaded:no-observer`` here.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from awiwi_drake.analysis import Samples, simulate
from awiwi_drake.components.friction import guide_friction_rate
from awiwi_drake.components.spring import hysteresis_rate
from awiwi_drake.components.tendon import series_stiffness
from awiwi_drake.control import closed_loop
from awiwi_drake.control.joint_design import joint_stage_controller
from awiwi_drake.control.joint_pd import joint_pd_controller
from awiwi_drake.hand.coupling import dof_selection, joint_stiffness
from awiwi_drake.parameters.hand import JointControllerParams
from awiwi_drake.parameters.hand_control import HandChainParams
from awiwi_drake.plotting import figure_axes, label_axes

__all__ = ["StiffnessMeasurement", "measure_joint_stiffness", "stiffness_bound", "cocontraction_study",
]

CONTROLLERS = ("joint-pd", "cascaded:no-observer")


@dataclass
class StiffnessMeasurement:
    """One finger, one loop, one co-contraction level: the measured static stiffness and its predictions.

    Matrices are over the finger's independent DoF (``dof_names``) [Nm/rad].  ``measured = L D^-1``; ``mechanical``:
    (5.12) of the springs at the ``tendon_force`` held before the load; ``predicted``: what the loop should show
    (module docstring), column ``j`` from the Dahl states held before load ``j`` and the directions it moves them;
    ``presliding`` the part of it from the hysteresis and guide Dahl states; ``commanded``: the chain's static
    stiffness per DoF (None for ``joint-pd``).  ``linearity``: the largest ``|delta x| / delta`` of a Dahl state over
    the loads (the presliding slope's secant is within ``linearity / 2`` of the tangent)."""

    finger: str
    controller: str
    level: str
    dof_names: list
    load: np.ndarray                 # per DoF [Nm]
    measured: np.ndarray
    mechanical: np.ndarray
    predicted: np.ndarray
    presliding: np.ndarray
    commanded: np.ndarray | None
    tendon_force: np.ndarray
    deflection: np.ndarray
    linearity: float
    ends: np.ndarray = field(repr=False, default=None)      # the windows' ends [s] (before the first load, then each)
    window: float = 0.0
    torque_error: np.ndarray = field(repr=False, default=None)   # per window, -(P S)^T f - tau_ref [Nm] (chain)
    estimation_error: np.ndarray = field(repr=False, default=None)   # per window, mean estimate - true [rad]
    t: np.ndarray = field(repr=False, default=None)
    q: np.ndarray = field(repr=False, default=None)

    def diagonal(self, which: str = "measured") -> np.ndarray:
        return np.diag(getattr(self, which)).copy()

    def plot(self, ax=None):
        """The measured stiffness per DoF (markers, :func:`stiffness_bound` as error bars) beside its prediction
        (line) and, under ``joint-pd``, the springs' (5.12) alone (dotted); log scale.  Measurements drawn on the
        same ``ax`` one after another sit side by side.  ``(fig, ax)``."""
        fig, ax = figure_axes(ax, figsize=(8, 4))
        i = len(ax.containers)                      # the measurements already on ax (one errorbar each)
        x = np.arange(len(self.dof_names)) + 0.08 * i
        line = ax.errorbar(x, self.diagonal(), yerr=stiffness_bound(self), fmt="o", ms=4, capsize=2,
                           label=f"{self.controller}, {self.level}")
        ax.plot(x, self.diagonal("predicted"), "-", color=line[0].get_color(), lw=1,
                label="predicted (lines), measured (markers)" if i == 0 else None)
        if self.controller == "joint-pd":
            ax.plot(x, self.diagonal("mechanical"), ":", color=line[0].get_color(), lw=1,
                    label="(5.12) springs alone" if i == 0 else None)
        ax.set_xticks(range(len(self.dof_names)))
        ax.set_xticklabels(self.dof_names)
        ax.set_yscale("log")
        label_axes(ax, ylabel="static joint stiffness [Nm/rad]", xlabel="DoF", title=f"{self.finger}: stiffness by "
                   "co-contraction, measured on the closed loop", legend=dict(fontsize="x-small", ncol=2))
        return fig, ax

    def table(self) -> str:
        rows = [f"{self.finger} {self.controller} ({self.level}), loads {np.array2string(self.load, precision=3)} Nm, "
                f"mean tendon force {self.tendon_force.mean():.1f} N",
                f"{'DoF':6s} {'measured':>9s} {'predicted':>9s} {'(5.12)':>9s} {'presliding':>10s} {'commanded':>9s}"]
        cmd = self.commanded if self.commanded is not None else np.full(len(self.dof_names), np.nan)
        for j, n in enumerate(self.dof_names):
            rows.append(f"{n:6s} {self.measured[j, j]:9.4f} {self.predicted[j, j]:9.4f} {self.mechanical[j, j]:9.4f} "
                        f"{self.presliding[j, j]:10.4f} {cmd[j]:9.4f}")
        return "\n".join(rows)


def _presliding(rig, f, x, P, z, g, s_x, s_h):
    """Presliding stiffness of the rig's two Dahl laws at their states ``z`` (spring hysteresis) and ``g`` (guides),
    for a small motion in the directions ``s_x`` of the elongations and ``s_h`` of the tendon paths (+-1 per
    tendon), at the measured forces ``f`` and elongations ``x``: per tendon the hysteresis' ``dz/dx = (w - s z) /
    delta_h`` (added to each spring's stiffness, N/m) and the guides' ``P^T diag((W - s g) / delta_g) P`` on the
    plant's joints (Nm/rad), each the law's own rate at unit speed (:func:`~awiwi_drake.components.spring.
    hysteresis_rate`, :func:`~awiwi_drake.components.friction.guide_friction_rate`).  A state at its level in the
    motion's direction gives 0 (it slides), at rest (0) the slope ``w / delta``."""
    model = rig.drive.model
    m = len(f)
    hyst = np.zeros(m)
    if model.has_hysteresis:
        hyst = np.asarray(hysteresis_rate(z, x, s_x, f - z, model.hysteresis), float) / s_x
    K_g = np.zeros((P.shape[1], P.shape[1]))
    gm = model.guide_friction
    if gm is not None:
        C, exponent = gm.levels()
        slope = np.asarray(guide_friction_rate(g, s_h, f, C, exponent, gm.presliding_length, gm.smoothing_velocity),
                           float) / s_h
        K_g = P.T @ np.diag(slope) @ P
    return hyst, K_g


def _smooth_staircase(n: int, load: np.ndarray, ramp: float, hold: float, settle: float, size: int, S: np.ndarray):
    """External torque samples: the load ramps (raised cosine over ``ramp`` s, quasi-static against the finger's
    link modes) onto DoF 0, then DoF 1, ...; returns the schedule and the windows' end times (before the first load, then
    after each)."""
    seg = ramp + hold
    u = np.linspace(0.0, 1.0, 41)
    shape = 0.5 - 0.5 * np.cos(np.pi * u)
    times, values = [0.0], [np.zeros(size)]
    level = np.zeros(size)
    for k in range(n):
        t0 = settle + k * seg
        times.append(t0)                      # held until the ramp starts (linear interpolation between samples)
        values.append(level.copy())
        for s_, a in zip(u[1:], shape[1:]):
            times.append(t0 + s_ * ramp)
            values.append(level + a * load[k] * S[:, k])
        level = level + load[k] * S[:, k]
    ends = settle + seg * np.arange(n + 1)
    return Samples(times, np.array(values), hold="linear"), ends


def measure_joint_stiffness(finger: str = "index", controller: str = "joint-pd", *, pretension: float = 20.0,
                            stiffness_scale: float = 1.0, load: float | None = 0.01, deflection: float | None = None,
                            ramp: float = 0.1, hold: float = 0.2, window: float = 0.1, settle: float | None = None,
                            params=None, **simulate_options) -> StiffnessMeasurement:
    """Measure the static joint stiffness of ``finger`` closed by ``controller`` (``joint-pd`` or
    ``cascaded:no-observer``, see the module docstring) at 3 kHz: the load ``load`` [Nm] (or, with ``deflection``
    [rad], per DoF that deflection times the loop's own stiffness of the design: the chain's commanded, joint-pd's
    (5.12) at the operating point, so that a soft DoF is not bent out of its linear range) ramps onto each DoF in
    turn (raised cosine over ``ramp`` s, then ``hold`` s), the deflection of each step is the change of the joint
    angles' mean over the last ``window`` s of each hold (the first load after ``settle`` s, default ``hold``).
    Co-contraction: ``pretension`` [N] (the operating point, both loops) and, for the chain, ``stiffness_scale`` (the
    distribution asked for that multiple of the operating point's (5.12)).  ``params``: a
    :class:`~awiwi_drake.parameters.hand.FingerRigParams` (default: the finger's, thesis physics on);
    ``finger="hand"``: the whole hand (wrist held).  ``simulate_options``: to
    :func:`~awiwi_drake.analysis.simulate` (default: fixed-step RK3 at the control period)."""
    from awiwi_drake.hand import finger_diagram, hand_diagram

    if controller not in CONTROLLERS:
        raise ValueError(f"measure_joint_stiffness: controller = {controller!r}; give one of {', '.join(CONTROLLERS)}")
    if not (window < hold):
        raise ValueError(f"measure_joint_stiffness: window = {window!r} s must be shorter than hold = {hold!r} s")
    rig = hand_diagram(wrist=False, params=params) if finger == "hand" else finger_diagram(finger=finger, params=params)
    op = rig.operating_point(pretension=pretension)
    S = dof_selection(rig.coupling)
    n = S.shape[1]
    if controller == "joint-pd":
        ctrl, commanded = joint_pd_controller(rig, op=op), None
        level = f"pretension {pretension:g} N"
    else:
        ctrl = joint_stage_controller(rig, "cascaded", op=op, chain=HandChainParams(stiffness_scale=stiffness_scale),
                                      friction_observer=None)
        commanded = np.asarray(ctrl.design.joint_design.static_stiffness, float)
        level = f"pretension {pretension:g} N, stiffness_scale {stiffness_scale:g}"
    if deflection is not None:
        L = deflection * (commanded if commanded is not None else np.diag(S.T @ op.joint_stiffness @ S))
    elif load is None:
        raise ValueError("measure_joint_stiffness: give load [Nm] or deflection [rad]")
    else:
        L = np.full(n, float(load))
    if not (np.all(np.isfinite(L)) and np.all(L != 0.0)):
        raise ValueError(f"measure_joint_stiffness: the loads {L} Nm must be finite and non-zero (load, deflection)")
    loop = closed_loop(rig, ctrl)
    sched, ends = _smooth_staircase(n, L, ramp, hold, hold if settle is None else settle, rig.num_joints, S)
    ctx = loop.create_context(op, references={"joint_angle_reference": op.joint_angle})
    ref_port, est_port = "controller_joint_torque_reference", "joint_angle_estimation_error"
    res = simulate(loop, ctx, float(ends[-1]), inputs={"external_torque": sched}, **simulate_options,
                   log=("joint_angle", "tendon_force", "elongation", "state")
                   + tuple(p_ for p_ in (ref_port, est_port) if loop.diagram.HasOutputPort(p_)))
    S_pinv = np.linalg.pinv(S)
    t, q = res.t, res["joint_angle"] @ S_pinv.T
    win = [(t > e - window) & (t <= e + 1e-12) for e in ends]

    def mean(a):                # per window
        return np.array([a[w].mean(axis=0) for w in win])
    D = np.diff(mean(q), axis=0).T                     # column j: the response to the load on DoF j
    measured = np.diag(L) @ np.linalg.inv(D)          # D = K^-1 diag(L)
    f = res["tendon_force"][win[0]].mean(axis=0)      # the forces held before the load
    x = np.asarray(rig.drive.model.laws.inverse_force(f), float)
    k_t = np.asarray(rig.spring_laws.stiffness(x), float)
    q0 = res["joint_angle"][win[0]].mean(axis=0)
    P = np.asarray(rig.coupling.P(q0))
    # the ring's and fifth's PIP/DIP coupler (5.16)-(5.17), a stiff spring between the two plant joints of one DoF
    K_c = np.zeros((rig.num_joints, rig.num_joints)) if rig.coupling_gain is None else \
        np.asarray(rig.coupling_gain, float)[:, :rig.num_joints]

    def on_dof(K_joints):       # the DoF stiffness the staircase measures: loads S L, deflections S^+ q
        return np.linalg.inv(S_pinv @ np.linalg.solve(K_joints, S))
    mechanical = on_dof(joint_stiffness(rig.coupling, q0, f, k_t) + K_c)
    # the Dahl states (mean per window) and each load's direction of motion, per tendon
    model, m = rig.drive.model, len(f)
    k0 = 2 * rig.num_joints + 2 * m
    zs = res["state"][:, k0:k0 + m] if model.has_hysteresis else np.zeros((len(t), m))
    gs = res["state"][:, k0 + m * model.has_hysteresis:][:, :m] if model.guide_friction is not None \
        else np.zeros((len(t), m))
    fw, xw, zw, gw = mean(res["tendon_force"]), mean(res["elongation"]), mean(zs), mean(gs)
    hw = mean(res["joint_angle"] @ P.T)
    c = JointControllerParams()
    r_m = rig.params.motor.pulley_radius

    def series(k, fj):          # each tendon's spring (and hysteresis) in series with its motor servo kp / r_m^2
        return joint_stiffness(rig.coupling, q0, fj, series_stiffness(k, c.kp / r_m ** 2)) + K_c
    D_pred, D_plain = np.zeros((n, n)), np.zeros((n, n))
    for j in range(n):          # column j from the states before load j and the directions it moves them
        s_x = np.where(xw[j + 1] >= xw[j], 1.0, -1.0)
        s_h = np.where(hw[j + 1] >= hw[j], 1.0, -1.0)
        kt_j = np.asarray(rig.spring_laws.stiffness(xw[j]), float)
        hyst, K_g = _presliding(rig, fw[j], xw[j], P, zw[j], gw[j], s_x, s_h)
        if controller == "joint-pd":
            K_j, K_0 = series(kt_j + hyst, fw[j]) + K_g, series(kt_j, fw[j])
            D_pred[:, j] = S_pinv @ np.linalg.solve(K_j, S[:, j] * L[j])
            D_plain[:, j] = S_pinv @ np.linalg.solve(K_0, S[:, j] * L[j])
        else:                   # the chain: its law on the DoF, the guides in parallel
            K_law = S_pinv.T @ np.diag(commanded) @ S_pinv
            D_pred[:, j] = S_pinv @ np.linalg.lstsq(K_law + K_g, S[:, j] * L[j], rcond=None)[0]
            D_plain[:, j] = S_pinv @ np.linalg.lstsq(K_law, S[:, j] * L[j], rcond=None)[0]
    predicted = np.diag(L) @ np.linalg.inv(D_pred)
    presliding = predicted - np.diag(L) @ np.linalg.inv(D_plain)
    # how far the Dahl states moved: the elongations' and the tendon paths' largest change over the run
    dx = np.ptp(res["elongation"], axis=0)
    dh = np.ptp(res["joint_angle"] @ P.T, axis=0)
    lin = 0.0
    if model.has_hysteresis:
        delta = np.array([h.presliding_length for h in model.hysteresis]) if isinstance(model.hysteresis, tuple) \
            else model.hysteresis.presliding_length
        lin = max(lin, float(np.max(dx / delta)))
    if model.guide_friction is not None:
        lin = max(lin, float(np.max(dh / model.guide_friction.presliding_length)))
    # the chain's static torque error per window, -(P S)^T f - tau_ref: what the distribution and the force loops did
    # not deliver of the joint law's request
    torque_error = np.zeros((len(ends), n))
    if ref_port in res:
        e_tau = -res["tendon_force"] @ (P @ S) - res[ref_port]
        torque_error = mean(e_tau)
    # the tendon-length estimator's (5.15) mean error per window (the chain acts on the estimate, not on q)
    estimation_error = np.zeros((len(ends), n))
    if est_port in res:
        estimation_error = mean(res[est_port]) @ S_pinv.T
    names = [rig.joint_names[int(np.flatnonzero(S[:, j])[0])] for j in range(n)]
    return StiffnessMeasurement(finger, controller, level, names, L, measured, mechanical, predicted, presliding,
                                commanded, f, D, lin, ends, window, torque_error, estimation_error, t, q)


def stiffness_bound(m: StiffnessMeasurement) -> np.ndarray:
    """Per DoF, how far ``m.measured``'s diagonal may lie from ``m.predicted``'s, derived from the run [Nm/rad]:

    * the Dahl states' secant: over a change ``u`` presliding lengths their force is ``w (1 - e^-u)``, whose secant
      slope lies within ``u / 2`` of the tangent ``w / delta`` the prediction uses: ``|presliding_jj| linearity / 2``;
    * the deflections' residual motion: each window's mean is within its largest deviation from that mean of the
      static value (the finger's light link modes ring for seconds at a damping ratio ~1e-3; the raised-cosine ramp
      keeps that small), so ``D`` is known within ``dD`` (the two windows' deviations added), and ``K = L D^-1``
      within ``|K| dD |D^-1|`` entry by entry (first order of ``dK = -K dD D^-1``);
    * the force chain's static torque error: the tendons deliver the joint law's request ``tau_ref`` but for
      ``-(P S)^T f - tau_ref`` (the warm-started distribution's and the force loops' residuals, the motors' friction
      and ripple); its change over load step ``j`` changes the torque behind column ``j`` of ``D``:
      ``|d tau_err,j| / |D_jj|``;
    * the tendon-length estimator (5.15): a loop that acts on the estimated joint angles holds the estimate's
      deflection ``D + dE`` (``dE`` the change of the windows' mean estimation error), so ``K`` within
      ``|K| |dE| |D^-1|`` entry by entry."""
    t, q = m.t, m.q
    dev = np.array([np.max(np.abs(q[w] - q[w].mean(axis=0)), axis=0)
                    for w in ((t > e - m.window) & (t <= e + 1e-12) for e in m.ends)])
    dD = (dev[:-1] + dev[1:]).T                       # column j: the windows before and after the load on DoF j
    dE = np.abs(np.diff(m.estimation_error, axis=0)).T
    ring = np.diag(np.abs(m.measured) @ (dD + dE) @ np.abs(np.linalg.inv(m.deflection)))
    force = np.abs(np.diag(np.diff(m.torque_error, axis=0))) / np.abs(np.diag(m.deflection))
    return np.abs(np.diag(m.presliding)) * m.linearity / 2.0 + ring + force


def cocontraction_study(finger: str = "index", *, pretensions=(20.0, 40.0), scales=(1.0, 2.0),
                        chain_params=None, **kw) -> list[StiffnessMeasurement]:
    """The stiffness measured at two or more co-contraction levels on ``finger``: ``joint-pd`` (motor positions held)
    at each of ``pretensions`` [N] with the thesis physics on, then the force chain (``cascaded:no-observer``) at each
    of ``scales`` (``stiffness_scale``, co-contraction through the distribution) on ``chain_params`` (default: the
    finger without its two Dahl states, hysteresis and guide friction, whose state after the co-contraction's own
    motion would decide the presliding stiffness; motor friction and ripple on), each DoF bent by 5 mrad (its
    commanded stiffness spans 0.007-0.5 Nm/rad), after 0.4 s for the distribution's co-contraction to settle.
    ``kw``: as :func:`measure_joint_stiffness`."""
    from awiwi_drake.parameters.hand import FingerRigParams

    if chain_params is None:
        chain_params = FingerRigParams.for_finger(finger).with_physics(hysteresis=False, guide_friction=False)
    runs = [measure_joint_stiffness(finger, "joint-pd", pretension=float(p), **kw) for p in pretensions]
    chain_kw = dict(dict(settle=0.4, deflection=0.005, load=None), **kw)
    runs += [measure_joint_stiffness(finger, "cascaded:no-observer", stiffness_scale=float(s), params=chain_params,
                                     **chain_kw) for s in scales]
    return runs
