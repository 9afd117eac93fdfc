"""Thesis ch. 15: closed-loop studies of the backstepping controllers (sections 15.1-15.5).

The controllers and their rig factories are :mod:`awiwi_drake.control.backstepping`
(``position_controller``, ``impedance_controller``); the scalar example of section
15.1 is :mod:`.ch15_scalar_example`. The study functions here run the simulations
behind Fig 15.2-15.4, 15.7-15.13, 15.16-15.21 and 15.23-15.27 and return data
(:class:`BacksteppingRun`); the ``plot_*`` functions at the end draw them.
All simulations go through :func:`awiwi_drake.analysis.simulate` (:func:`run_loop`, :func:`event_schedules`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Mapping, Sequence

import numpy as np

from awiwi_drake.analysis import PerEntry, Samples, Sine, linearize, simulate
from awiwi_drake.components.spring import LinearSpring
from awiwi_drake.control.backstepping import (
    REFERENCE_PORT, REFERENCE_SIZE, impedance_backstepping, impedance_controller, joint_model, position_controller)
from awiwi_drake.control.base import ClosedLoop, closed_loop
from awiwi_drake.control.sensors import with_external_torque_sensor
from awiwi_drake.parameters.backstepping import (
    AntagonisticBacksteppingGains, BacksteppingPlantParams, ImpedanceBacksteppingGains, ImpedanceStudy,
    NonlinearImpedanceStudy, PositionBacksteppingGains, PositionStudy, ScalarExampleGains)
from awiwi_drake.parameters.rigs import FlexibleJointParams, JointRigParams
from awiwi_drake.plotting import figure_axes, label_axes
from awiwi_drake.reproductions.ch11_impedance import GainDiagram
from awiwi_drake.reproductions.ch15_scalar_example import ScalarBackstepping, ScalarExamplePlant, example_dynamics
from awiwi_drake.rigs import flexible_joint_rig, joint_rig

__all__ = [
    "BacksteppingRun", "StiffnessCheck", "table_15_1_params", "table_15_1_rig", "event_schedules", "run_loop",
    "example_phase_portrait", "position_gain_study", "saturation_study", "delay_study", "impedance_study",
    "impedance_steady_state", "nonlinear_impedance_study", "load_step_command_jump", "antagonistic_step",
    "antagonistic_sine", "antagonistic_stiffness_check", "sine_reference", "is_monotone_nonincreasing", "count_oscillations",
    "gain_diagram_study", "plot_run_traces", "plot_joint_angle",
    "plot_command", "plot_phase_portrait",
]


@dataclass
class BacksteppingRun:
    """Sampled time series of one closed-loop simulation: ``label`` (what was varied, e.g. ``"K1 = 5"``), ``t`` [s],
    the rig ``state`` (N, n) (``[q, qd, theta..., omega...]``), the ``command`` (N, m) entering the rig [Nm] (after
    hold, delay, saturation), the controller's ``lyapunov`` function, the link-angle ``reference`` [rad], the
    external torque ``disturbance`` [Nm]; where the run logged them (``run_loop``'s ``extra_outputs``) the loop's
    ``tendon_force`` [N], ``joint_torque`` [Nm] and ``tendon_stiffness`` [N/m], and for Fig 9.3 the (9.2) observer's
    ``friction_estimate`` [Nm] (the true friction is ``disturbance``)."""

    label: str
    t: np.ndarray
    state: np.ndarray
    command: np.ndarray
    lyapunov: np.ndarray
    reference: np.ndarray
    disturbance: np.ndarray
    tendon_force: np.ndarray | None = None
    joint_torque: np.ndarray | None = None
    tendon_stiffness: np.ndarray | None = None
    friction_estimate: np.ndarray | None = None

    @property
    def q(self) -> np.ndarray:
        """Link angle [rad]."""
        return self.state[:, 0]

    def plot(self, ax=None, **kw):
        """Link angle and reference (:func:`plot_joint_angle`)."""
        return plot_joint_angle([self], ax=ax, **kw)


@dataclass
class StiffnessCheck:
    """Fig 15.27: closed-loop static stiffness ``effective_stiffness`` [Nm/rad] per ``stiffness`` (Kp,imp)
    [Nm/rad], and the joint ``torque`` [Nm] it gives under the imposed ``deflection`` [rad]."""

    stiffness: np.ndarray
    effective_stiffness: np.ndarray
    torque: np.ndarray
    deflection: float

    def plot(self, ax=None):
        fig, ax = figure_axes(ax)
        ax.plot(self.stiffness, self.torque, "o-", label=f"deflection {self.deflection:g} rad")
        label_axes(ax, "joint torque [Nm]", xlabel="Kp,imp [Nm/rad]", legend=dict(fontsize="small"))
        return fig, ax


# ---------------------------------------------------------------------------
# rigs and models
def table_15_1_params(**changes) -> FlexibleJointParams:
    """FlexibleJointParams with the Table 15.1 values (m = 7.2e-7, b = 2e-4, b_th = 1e-2, b_q = 1e-3, K = 20)."""
    t = BacksteppingPlantParams()
    p = FlexibleJointParams(link_inertia=t.link_inertia, motor_inertia=t.motor_inertia, stiffness=t.stiffness,
                            link_damping=t.link_damping, motor_damping=t.motor_damping)
    return p.replace(**changes) if changes else p


def table_15_1_rig(*, spring: str = "linear", **changes):
    """``flexible_joint_rig`` with Table 15.1 parameters (``spring="nonlinear"``: lever-spring pair)."""
    return flexible_joint_rig(params=table_15_1_params(**changes), spring=spring)


# ---------------------------------------------------------------------------
# simulation: schedules from input events, one run through analysis.simulate
def event_schedules(events: Sequence[tuple[float, Mapping[str, object]]], initial: Mapping[str, object] | None = None
                    ) -> dict:
    """Piecewise-constant input schedules from ``initial`` values and ``[(t, {port: value}), ...]`` events.

    Each port gets a :class:`~awiwi_drake.analysis.Samples` (zero-order hold) starting at its
    initial value (0 if not given); a value is a number (every entry of the port) or a vector.
    """
    initial = dict(initial or {})
    names = list(dict.fromkeys([*initial, *(k for _, vals in events for k in vals)]))
    out = {}
    for name in names:
        times, values = [0.0], [initial.get(name, 0.0)]
        for te, vals in sorted(events, key=lambda e: e[0]):
            if name in vals:
                if te <= 0.0:
                    values[0] = vals[name]
                else:
                    times.append(float(te))
                    values.append(vals[name])
        arr = np.array([np.ravel(np.asarray(v, float)) for v in values], dtype=float)
        out[name] = Samples(times, arr[:, 0] if arr.shape[1] == 1 else arr)
    return out


#: Integrator of the impedance and antagonistic backstepping runs (continuous loops): their fast poles (K3, K4 and
#: Kd,imp / m with Table 15.1's small link inertia) make error-controlled explicit RK3 stability-limited; the L-stable
#: Radau IIA (3rd order) at the same accuracy is 3-4x faster.  Not for the position/saturation studies (not stiff).
STIFF_INTEGRATOR = "radau3"


def run_loop(loop: ClosedLoop, *, t_final: float, state0, motor_torque0=None, inputs: Mapping[str, object] | None = None,
             dt: float = 1e-3, max_step: float = 1e-3, accuracy: float = 1e-6, label: str = "",
             extra_outputs: Sequence[str] = (), integrator: str = "runge_kutta3") -> BacksteppingRun:
    """One closed-loop run through :func:`awiwi_drake.analysis.simulate`, logged every ``dt`` as a :class:`BacksteppingRun`.

    ``inputs`` maps exported inputs (``joint_angle_reference``, ``external_torque``) to schedules
    (:func:`event_schedules`, ``Sine``, ``PerEntry``, ...); the others stay 0. ``extra_outputs``: outputs also
    logged into the run's fields of the same name (``tendon_force``, ``joint_torque``, ``tendon_stiffness``).
    ``integrator``: the error-controlled Drake integrator of a continuous loop (see :data:`STIFF_INTEGRATOR`).
    """
    unknown = [k for k in extra_outputs if k not in _EXTRA_OUTPUTS]
    if unknown:
        raise ValueError(f"run_loop: extra_outputs {unknown} are not BacksteppingRun fields; "
                         f"known: {', '.join(_EXTRA_OUTPUTS)}")
    d = loop.diagram
    ctx = loop.create_context(state=state0, motor_torque=motor_torque0)
    log = ["state", "motor_torque", *extra_outputs]
    has_v = d.HasOutputPort("controller_lyapunov")
    ref = REFERENCE_PORT if d.HasInputPort(REFERENCE_PORT) else None
    ext = "external_torque" if d.HasInputPort("external_torque") else None
    log += [p for p in (("controller_lyapunov" if has_v else None), ref, ext) if p]
    res = simulate(loop, ctx, t_final, inputs=inputs, log=log, log_period=dt, max_step=max_step, accuracy=accuracy,
                   integrator=integrator)
    n = len(res.t)
    return BacksteppingRun(label, res.t, res["state"], res["motor_torque"],
                           res["controller_lyapunov"][:, 0] if has_v else np.full(n, math.nan),
                           res[ref][:, 0] if ref else np.full(n, math.nan),
                           res[ext][:, 0] if ext else np.zeros(n), **{k: res[k] for k in extra_outputs})


_EXTRA_OUTPUTS = ("tendon_force", "joint_torque", "tendon_stiffness")


def is_monotone_nonincreasing(v, *, rtol: float = 1e-6, atol: float = 1e-12) -> bool:
    """True when ``v`` never increases by more than ``rtol * max|v| + atol`` between samples."""
    v = np.asarray(v, dtype=float)
    return bool(np.all(np.diff(v) <= rtol * np.max(np.abs(v)) + atol))


def count_oscillations(t, y, target, *, after: float = 0.0, band: float = 0.02) -> int:
    """Number of crossings of ``target`` by ``y`` (outside a ``band`` of the step) after ``after`` s.

    A monotone (non-oscillating) step response crosses its target at most once.
    """
    t, y = np.asarray(t), np.asarray(y)
    e = (y - target)[t >= after]
    scale = max(abs(target), 1e-12)
    s = np.sign(np.where(np.abs(e) > band * scale, e, 0.0))
    s = s[s != 0]
    return int(np.sum(s[1:] != s[:-1]))


# ---------------------------------------------------------------------------
# 15.1: scalar example
def example_phase_portrait(gains: ScalarExampleGains, initial_states, *, t_final: float = 60.0,
                           variant: str = "textbook", dt: float = 0.05) -> list[BacksteppingRun]:
    """Trajectories of (15.1) under (15.10) from each initial state (Fig 15.2-15.4)."""
    runs = []
    for x0 in initial_states:
        plant = SimpleNamespace(name="scalar-example", diagram=ScalarExamplePlant())   # (15.1) as the rig
        loop = closed_loop(plant, ScalarBackstepping(gains, variant), rate_hz=None)
        runs.append(run_loop(loop, t_final=t_final, state0=x0, dt=dt, max_step=0.05,
                             label=f"x0 = ({x0[0]:g}, {x0[1]:g})"))
    return runs


def _run(make_controller, *, make_rig=None, op=None, rate_hz=None, delay=None, saturation=None, **kw):
    """:func:`run_loop` on a fresh rig (a Drake diagram joins one closed loop only; default
    :func:`table_15_1_rig`) closed by ``make_controller(rig)``, from ``rig.operating_point(**op)``."""
    rig = (make_rig or table_15_1_rig)()
    loop = closed_loop(rig, make_controller(rig), rate_hz=rate_hz, delay=delay, saturation=saturation)
    x0 = rig.operating_point(**(op or {}))
    return run_loop(loop, state0=x0.state, motor_torque0=x0.motor_torque, **kw)


# ---------------------------------------------------------------------------
# 15.2: position control, linear flexible joint
def _step_run(make_controller, *, step, dt=2e-3, max_step=2e-3, **kw):
    return _run(make_controller, inputs=event_schedules((), {REFERENCE_PORT: step}), dt=dt, max_step=max_step, **kw)


def position_gain_study(which: str = "k1", study: PositionStudy | None = None, *, t_final: float | None = None,
                        values: Sequence[float] | None = None) -> list[BacksteppingRun]:
    """0.8 rad steps for K1 in {0.2, 1, 5, 50} (K2 = 1, Fig 15.7) or K2 in the same set (K1 = 5, Fig 15.8)."""
    s = study or PositionStudy()
    if which == "k1":
        vals, make = values or s.k1_values, (lambda v: PositionBacksteppingGains(k1=v, k2=s.k1_fixed_k2))
    elif which == "k2":
        vals, make = values or s.k2_values, (lambda v: PositionBacksteppingGains(k1=s.k2_fixed_k1, k2=v))
    else:
        raise ValueError(f"position_gain_study: which = {which!r} must be 'k1' or 'k2'")
    return [_step_run(lambda rig, v=v: position_controller(rig, make(v)), step=s.step,
                      t_final=t_final or s.duration, label=f"{which.upper()} = {v:g}") for v in vals]


def saturation_study(study: PositionStudy | None = None, *, t_final: float | None = None) -> list[BacksteppingRun]:
    """0.8 rad step without and with |u| < 5e-4 Nm (K1 = K2 = 1, K3 = K4 = 100; Fig 15.10-15.11)."""
    s = study or PositionStudy()
    g = PositionBacksteppingGains(k1=s.saturation_k1, k2=s.saturation_k2)
    return [_step_run(lambda rig: position_controller(rig, g), step=s.step, t_final=t_final or s.duration,
                      label=lbl, saturation=sat)
            for lbl, sat in (("no saturation", None), (f"|u| < {s.saturation:g} Nm", s.saturation))]


def delay_study(study: PositionStudy | None = None, *, t_final: float | None = None,
                delays: Sequence[float] | None = None) -> list[BacksteppingRun]:
    """0.8 rad steps with round-trip delays (K1 = 5, K2 = 1; Fig 15.13).

    A delay ``d > 0`` is realised by ctrl1's :func:`closed_loop`: the controller is sampled
    every ``d / delay_steps`` s and its command delayed by ``delay_steps`` periods (for a
    static state feedback, a delay on the command equals the same total delay split between
    measurement and command, the thesis's Fig 15.12).
    """
    s = study or PositionStudy()
    g = PositionBacksteppingGains()
    return [_step_run(lambda rig: position_controller(rig, g), step=s.step, t_final=t_final or s.delay_duration,
                      label=f"delay {1e3 * d:g} ms",
                      **(dict(delay=d, rate_hz=s.delay_steps / d, max_step=min(2e-3, d)) if d > 0 else {}))
            for d in (delays if delays is not None else s.delays)]


# ---------------------------------------------------------------------------
# 15.3: impedance control, linear flexible joint
def _impedance_run(make_rig, make_controller, s, **kw):
    """The step at ``s.step_time`` and the load step at ``s.disturbance_time`` of study ``s``."""
    events = [(s.step_time, {REFERENCE_PORT: s.step}), (s.disturbance_time, {"external_torque": s.disturbance})]
    return _run(make_controller, make_rig=make_rig, inputs=event_schedules(events), dt=2e-3, max_step=1e-3,
                integrator=STIFF_INTEGRATOR, **kw)


def impedance_study(which: str = "stiffness", study: ImpedanceStudy | None = None, *,
                    t_final: float | None = None, values: Sequence[float] | None = None,
                    gains: ImpedanceBacksteppingGains | None = None,
                    external_torque: str = "input") -> list[BacksteppingRun]:
    """45 deg step at 0.5 s, 0.2 Nm disturbance at 1.5 s (Fig 15.16: Kp,imp; Fig 15.17: Kd,imp).

    ``external_torque="input"`` (default) measures the load with an ideal sensor
    (:func:`with_external_torque_sensor`), as the design (15.62) formally requires;
    ``"observer"`` estimates it with (9.2); ``"none"`` ignores it.
    """
    s = study or ImpedanceStudy()
    g0 = gains or ImpedanceBacksteppingGains()
    if which == "stiffness":
        vals = values or s.stiffness_values
        make = lambda v: g0.replace(stiffness=v, damping=s.stiffness_fixed_damping)  # noqa: E731
        label = "Kp,imp = {:g} Nm/rad"
    elif which == "damping":
        vals = values or s.damping_values
        make = lambda v: g0.replace(stiffness=s.damping_fixed_stiffness, damping=v)  # noqa: E731
        label = "Kd,imp = {:g} Nm s/rad"
    else:
        raise ValueError(f"impedance_study: which = {which!r} must be 'stiffness' or 'damping'")
    make_rig = (lambda: with_external_torque_sensor(table_15_1_rig())) if external_torque == "input" \
        else table_15_1_rig
    return [_impedance_run(make_rig, lambda rig, v=v: impedance_controller(rig, make(v), external_torque=external_torque),
                           s, t_final=t_final or s.duration, label=label.format(v)) for v in vals]


def impedance_steady_state(rig, gains: ImpedanceBacksteppingGains, disturbance: float, **kw) -> float:
    """Steady-state deflection ``q_ss - r`` [rad] under a constant external torque, from the closed loop.

    Drake's ``Linearize`` of the (linear) closed loop gives ``x' = A x + B w``; the
    steady state is ``-A^-1 B w``. ``kw`` go to :func:`impedance_controller`.
    """
    loop = closed_loop(rig, impedance_controller(rig, gains, **kw), rate_hz=None)
    lin = linearize(loop.diagram, context=loop.create_context(state=rig.operating_point().state),
                    input="external_torque", outputs=("joint_angle",))
    return float((lin.C @ -np.linalg.solve(lin.A, lin.B @ [disturbance]))[0])


# ---------------------------------------------------------------------------
# 15.4: nonlinear spring
def nonlinear_impedance_study(study: NonlinearImpedanceStudy | None = None, *, saturation: bool = False,
                              t_final: float | None = None, external_torque: str = "input") -> list[BacksteppingRun]:
    """Linear vs nonlinear backstepping impedance controller on the nonlinear-spring joint (Fig 15.19-15.21).

    The "linear controller" designs with the spring's stiffness at zero deflection; the
    "nonlinear controller" uses the real spring curve and its first two derivatives.
    ``saturation=True`` limits the motor torque (Fig 15.21).

    The load is an ideal step, measured by an ideal sensor: it enters the design's ``qdd``/``qddd`` and the
    command jumps by :func:`load_step_command_jump` (what that does: docs/REPRODUCTIONS.md).
    """
    s = study or NonlinearImpedanceStudy()
    base = functools.partial(table_15_1_rig, spring="nonlinear")
    make_rig = (lambda: with_external_torque_sensor(base())) if external_torque == "input" else base
    g = ImpedanceBacksteppingGains(stiffness=s.stiffness, damping=s.damping, k3=s.k3, k4=s.k4)
    k0 = float(np.ravel(make_rig().spring.stiffness(np.array([0.0])))[0])
    sat = s.torque_limit if saturation else None
    return [_impedance_run(make_rig, lambda rig, law=law: impedance_controller(rig, g, spring=law,
                                                                                external_torque=external_torque),
                           s, t_final=t_final or s.duration, label=label, saturation=sat,
                           extra_outputs=("tendon_stiffness",))
            for label, law in (("nonlinear controller", None),
                               ("linear controller", LinearSpring(k0, tension_only=False)))]


def load_step_command_jump(study: NonlinearImpedanceStudy | None = None, *, spring=None) -> float:
    """Jump of the impedance command [Nm] when the measured load steps from 0 to ``study.disturbance``.

    Evaluated with the law :func:`~awiwi_drake.control.backstepping.impedance_backstepping` at rest
    at the reference ``study.step`` (the state just before the load of Fig 15.19); ``spring`` is the
    design law as in :func:`nonlinear_impedance_study` (``None``: the rig's nonlinear spring).
    """
    s = study or NonlinearImpedanceStudy()
    model = joint_model(table_15_1_rig(spring="nonlinear"), spring=spring)
    g = ImpedanceBacksteppingGains(stiffness=s.stiffness, damping=s.damping, k3=s.k3, k4=s.k4)
    x = np.array([s.step, 0.0, s.step, 0.0])
    r = np.array([s.step, 0.0, 0.0, 0.0, 0.0])
    u = [impedance_backstepping(x, r, model, g, w)[0][0] for w in (0.0, s.disturbance)]
    return float(u[1] - u[0])


# ---------------------------------------------------------------------------
# 15.5: antagonistic joint
def sine_reference(amplitude, freq, offset=0.0) -> PerEntry:
    """``offset + A sin(w t)`` and its four derivatives ``A w^k sin(w t + k pi / 2)`` (the reference port)."""
    w = 2 * math.pi * freq
    return PerEntry([Sine(amplitude * w ** k, freq, phase=k * math.pi / 2, offset=offset if k == 0 else 0.0)
                     for k in range(REFERENCE_SIZE)])


def antagonistic_step(gains: AntagonisticBacksteppingGains | None = None, *, step: float = math.radians(30.0),
                      t_final: float = 0.8, make_rig=None, dt: float = 1e-3) -> BacksteppingRun:
    """Step of the antagonistic joint (Fig 15.24: 30 deg PIP step), joint rig defaults."""
    g = gains or AntagonisticBacksteppingGains()
    return _run(lambda rig: impedance_controller(rig, g), make_rig=make_rig or joint_rig,
                op=dict(pretension=g.pretension), t_final=t_final,
                inputs=event_schedules([(0.05, {REFERENCE_PORT: step})]), dt=dt, max_step=1e-3,
                label="backstepping step", extra_outputs=("tendon_force", "joint_torque"), integrator=STIFF_INTEGRATOR)


def antagonistic_sine(gains: AntagonisticBacksteppingGains | None = None, *, amplitude: float = math.radians(25.0),
                      frequency: float = 1.0, offset: float = math.radians(30.0), t_final: float = 2.0, make_rig=None,
                      feedforward: bool = True, dt: float = 1e-3) -> BacksteppingRun:
    """Sine tracking of the antagonistic joint (Fig 15.25: 10-55 deg at about 1 Hz).

    ``feedforward=True`` feeds the reference derivatives (``reference_derivatives=4``); otherwise
    the controller sees the reference value only (regulation design).
    """
    g = gains or AntagonisticBacksteppingGains()
    ref = sine_reference(amplitude, frequency, offset)
    return _run(lambda rig: impedance_controller(rig, g, reference_derivatives=REFERENCE_SIZE - 1 if feedforward else 0),
                make_rig=make_rig or joint_rig, op=dict(pretension=g.pretension, joint_angle=offset), t_final=t_final,
                inputs={REFERENCE_PORT: ref if feedforward else PerEntry(ref.entries[:1])}, dt=dt, max_step=dt,
                label="backstepping sine", extra_outputs=("tendon_force",))


def antagonistic_stiffness_check(stiffness_values: Sequence[float], *, deflection: float = 0.3,
                                 gains: AntagonisticBacksteppingGains | None = None,
                                 load: float = 0.01) -> StiffnessCheck:
    """Fig 15.27: joint torque from the tendon forces under an imposed deflection, per Kp,imp.

    At steady state the tendon torque balances whatever holds the link, so imposing a
    deflection ``delta`` with a fixture gives the torque ``K_eff delta`` where ``K_eff`` is the
    static stiffness of the closed loop. ``K_eff`` is computed exactly from Drake's
    linearisation of the joint rig + controller at the pretension operating point
    (:func:`impedance_steady_state` with a small ``load`` [Nm]); the returned
    ``torque = K_eff * deflection`` [Nm] is the quantity plotted in Fig 15.27.
    (A simulated stiff fixture excites a link mode far above the torque loops' bandwidth:
    the design's assumption of a constant external torque no longer holds.)
    """
    g0 = gains or AntagonisticBacksteppingGains()
    k_eff = []
    for kp in stiffness_values:
        g = g0.replace(stiffness=float(kp))
        rig = joint_rig(params=JointRigParams().replace(pretension=g.pretension))
        dq = impedance_steady_state(rig, g, load)
        k_eff.append(load / dq)
    k_eff = np.array(k_eff)
    return StiffnessCheck(np.array(stiffness_values, dtype=float), k_eff, k_eff * deflection, float(deflection))


# ---------------------------------------------------------------------------
# plots: runs in, ``(fig, ax)`` out
def gain_diagram_study(controllers: Sequence[str] = ("backstepping", "two-time-scale"), *,
                       freqs: Sequence[float] | None = None) -> list[GainDiagram]:
    """Fig 15.26: gain diagrams of the registered ``controllers`` on the antagonistic joint rig at its default
    operating point (20 N, the figure's pretension), each continuous loop settled as compare settles it
    (:func:`~awiwi_drake.control.compare.runner.settle`, ``compare_test_params``) and linearised there; default
    frequencies 1-70 Hz (the figure's axis), 300 log-spaced.  The 3 kHz chirp of the same comparison is ``awiwi-drake
    compare --rig joint-rig --controllers backstepping,two-time-scale --tests sweep --rate 3000``."""
    from awiwi_drake.control.compare import build_loops, compare_test_params
    from awiwi_drake.control.compare.metrics import linear_bandwidth
    from awiwi_drake.control.compare.runner import settle

    f = np.logspace(0.0, math.log10(70.0), 300) if freqs is None else np.asarray(freqs, dtype=float)
    out = []
    for name, loop in build_loops(joint_rig, list(controllers), rate_hz=None).items():
        p = compare_test_params(loop.rig)
        ctx = settle(loop, p.initial_reference, t_settle=p.settle_time, max_step=p.max_step)
        lin = linearize(loop.diagram, context=ctx, input=loop.references[0], outputs=(loop.tracked_outputs[0],),
                        equilibrium_tolerance=None)
        gain = np.abs(lin.bode(0, omega=2 * np.pi * f).response)
        out.append(GainDiagram(name, f, gain, lin.poles, linear_bandwidth(lin), lin, loop))
    return out


def plot_run_traces(runs, signal, ylabel, *, ax=None, title: str = "", reference: bool = False):
    """``signal(run)`` of each :class:`BacksteppingRun` over its time, labelled; the first run's reference dashed."""
    fig, ax = figure_axes(ax)
    for r in runs:
        ax.plot(r.t, signal(r), label=r.label)
    if reference and len(runs) and np.all(np.isfinite(runs[0].reference)):
        ax.plot(runs[0].t, runs[0].reference, "k--", lw=0.8, label="reference")
    label_axes(ax, ylabel, title=title, legend=dict(fontsize="small"))
    return fig, ax


def plot_joint_angle(runs, *, ax=None, reference: bool = True, title: str = ""):
    """Link angle of each run (Fig 15.7, 15.8, 15.10, 15.13, 15.16, 15.17, 15.19)."""
    return plot_run_traces(runs, lambda r: r.q, "link angle [rad]", ax=ax, title=title, reference=reference)


def plot_command(runs, *, ax=None, title: str = ""):
    """Motor torque entering the plant (Fig 15.11)."""
    return plot_run_traces(runs, lambda r: r.command[:, 0], "motor torque [Nm]", ax=ax, title=title)


def plot_phase_portrait(runs, *, ax=None, title: str = ""):
    """Phase diagram ``x1' (x1)`` of the scalar example (Fig 15.2-15.4); crosses mark the starts."""
    fig, ax = figure_axes(ax)
    for r in runs:
        x1 = r.state[:, 0]
        x1d = np.array([example_dynamics(x, 0.0)[0] for x in r.state])
        ax.plot(x1, x1d, lw=1)
        ax.plot(x1[0], x1d[0], "kx")
    label_axes(ax, "dx1/dt", xlabel="x1", title=title, legend=None)
    return fig, ax
