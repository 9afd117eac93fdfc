"""Simulation with Drake's ``Simulator``, logging and health monitors.

:func:`simulate` runs a diagram, records named output ports at every
integrator step, and watches for

* divergence - a non-finite or exploding state raises :class:`SimulationDivergedError`
  naming the time and the state entry;
* tendon slack - tendon force at or below ``slack_force`` (a tendon-driven hand's
  model is invalid then, ch. 7);
* actuator saturation - commanded torque beyond the motor's limit.

Slack and saturation are recorded as :class:`Event` intervals in the
:class:`SimulationResult` (and optionally raise).
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence

import numpy as np
from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
from pydrake.systems.framework import Context, Diagram, EventStatus, OutputPort, System

__all__ = ["SimulationDivergedError", "Event", "SimulationResult", "SlackMonitor", "SaturationMonitor",
           "OverrangeMonitor", "PairSlackMonitor",
           "simulate", "rig_monitors"]


class SimulationDivergedError(RuntimeError):
    """The state became non-finite or exceeded the divergence bound."""


@dataclass
class Event:
    """An interval during which a condition held for one channel.

    Conditions are checked after every integrator step, so ``t_start`` and
    ``t_end`` are the first and last step times at which it held (within one
    step, at most ``max_step``, of the true crossing), and ``extreme`` is the
    most extreme sampled value.
    """

    kind: str
    channel: str
    t_start: float
    t_end: float
    extreme: float

    def __str__(self) -> str:
        return f"{self.kind} on {self.channel} from {self.t_start:.4g} s to {self.t_end:.4g} s (extreme {self.extreme:.4g})"


@dataclass
class SimulationResult:
    """Logged signals (one row per integrator step) and detected events.

    Attributes
    ----------
    t : ndarray (T,)
    signals : dict of name -> ndarray (T, k)
    events : list of Event
    final_context : Context
    """

    t: np.ndarray
    signals: dict
    events: list = field(default_factory=list)
    final_context: Context | None = None

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self.signals:
            raise KeyError(f"signal {name!r} was not logged; logged: {', '.join(self.signals)}")
        return self.signals[name]

    def events_of(self, kind: str) -> list:
        return [e for e in self.events if e.kind == kind]

    def resample(self, t: np.ndarray) -> "SimulationResult":
        """Signals linearly interpolated at times ``t`` (for comparisons and plots)."""
        out = {k: np.stack([np.interp(t, self.t, v[:, j]) for j in range(v.shape[1])], axis=1)
               for k, v in self.signals.items()}
        return SimulationResult(np.asarray(t), out, list(self.events), self.final_context)


class _IntervalMonitor(abc.ABC):
    """Track per-channel intervals where ``condition(value)`` holds on one port."""

    kind = "condition"

    def __init__(self, system: System, port, labels: Sequence[str] | None = None, raise_on_event: bool = False):
        self.system, self.port = system, port
        self.labels = labels
        self.raise_on_event = raise_on_event
        self._open: dict[int, Event] = {}
        self.events: list[Event] = []

    @abc.abstractmethod
    def _condition(self, v: np.ndarray) -> np.ndarray:
        """Boolean per channel: does the condition hold?"""

    def _extreme(self, old: float, v: float) -> float:
        return max(old, v)

    def reset(self) -> None:
        """Forget events (called by :func:`simulate` before each run)."""
        self._open, self.events = {}, []

    def check(self, root: Context) -> str | None:
        return self._check_values(root.get_time(), self.port.Eval(self.system.GetMyContextFromRoot(root)))

    def _check_values(self, t: float, v) -> str | None:
        hit = self._condition(v)
        for i in range(len(v)):
            if hit[i]:
                if i not in self._open:
                    label = self.labels[i] if self.labels else f"{self.port.get_name()}[{i}]"
                    self._open[i] = Event(self.kind, label, t, t, float(v[i]))
                    if self.raise_on_event:
                        return f"{self.kind} on {label} at t = {t:.6g} s (value {v[i]:.6g})"
                ev = self._open[i]
                ev.t_end, ev.extreme = t, self._extreme(ev.extreme, float(v[i]))
            elif i in self._open:
                self.events.append(self._open.pop(i))
        return None

    def finish(self) -> list[Event]:
        self.events.extend(self._open.values())
        self._open.clear()
        return sorted(self.events, key=lambda e: e.t_start)


class SlackMonitor(_IntervalMonitor):
    """Tendon slack: the force on output ``port_name`` at or below ``slack_force`` [N]."""

    kind = "tendon_slack"

    def __init__(self, system, port_name="tendon_force", slack_force: float = 0.0, **kw):
        super().__init__(system, system.GetOutputPort(port_name), **kw)
        self.slack_force = slack_force

    def _condition(self, v):
        return v <= self.slack_force

    def _extreme(self, old, v):
        return min(old, v)


class OverrangeMonitor(_IntervalMonitor):
    """Spring beyond its calibrated range: force on ``port_name`` above ``max_force`` [N]."""

    kind = "spring_overrange"

    def __init__(self, system, max_force: float, port_name="tendon_force", **kw):
        super().__init__(system, system.GetOutputPort(port_name), **kw)
        self.max_force = max_force

    def _condition(self, v):
        return v > self.max_force


class SaturationMonitor(_IntervalMonitor):
    """Actuator saturation: ``|commanded torque| >= torque_limit`` on input ``port_name``."""

    kind = "actuator_saturation"

    def __init__(self, system, torque_limit: float, port_name="motor_torque", **kw):
        super().__init__(system, system.GetInputPort(port_name), **kw)
        self.torque_limit = torque_limit

    def _condition(self, v):
        return np.abs(v) >= self.torque_limit

    def _extreme(self, old, v):
        return old if abs(old) >= abs(v) else v


class PairSlackMonitor(_IntervalMonitor):
    """Slack in an antagonistic torsional spring ``phi(d)`` (flexible joint, nonlinear spring).

    The pair's tendons have elongations ``x0 + r d`` and ``x0 - r d`` with
    ``d = theta - q`` (state entries ``i_theta`` and ``i_q``); a tendon is slack when
    its elongation is <= 0.
    """

    kind = "tendon_slack"

    def __init__(self, system, x0: float, radius: float, i_q: int = 0, i_theta: int = 2, **kw):
        super().__init__(system, system.GetOutputPort("state"), labels=["pair tendon 1", "pair tendon 2"], **kw)
        self.x0, self.r, self.i_q, self.i_theta = x0, radius, i_q, i_theta

    def check(self, root):
        x = self.port.Eval(self.system.GetMyContextFromRoot(root))
        d = x[self.i_theta] - x[self.i_q]
        elong = np.array([self.x0 + self.r * d, self.x0 - self.r * d])
        return self._check_values(root.get_time(), elong)

    def _condition(self, v):
        return v <= 0.0


def rig_monitors(rig, *, raise_on_slack: bool = False, raise_on_saturation: bool = False) -> list:
    """Slack, over-range and saturation monitors for a rig.

    ``rig.extra`` says what applies: ``tension_only`` (slack on ``tendon_force``),
    ``pair_slack`` (slack of the two hidden tendons of an antagonistic torsional
    spring, from the ``state`` output), ``max_force`` (calibrated spring range)
    and ``torque_limit``.
    """
    monitors = []
    if rig.extra.get("tension_only", True):
        monitors.append(SlackMonitor(rig.diagram, raise_on_event=raise_on_slack))
    if rig.extra.get("pair_slack") is not None:
        monitors.append(PairSlackMonitor(rig.diagram, *rig.extra["pair_slack"], raise_on_event=raise_on_slack))
    if rig.extra.get("max_force") is not None:
        monitors.append(OverrangeMonitor(rig.diagram, rig.extra["max_force"]))
    limit = rig.extra.get("torque_limit")
    if limit is not None:
        monitors.append(SaturationMonitor(rig.diagram, limit, raise_on_event=raise_on_saturation))
    return monitors


def _resolve_ports(diagram: Diagram, log) -> list[tuple[str, System, OutputPort]]:
    out = []
    if isinstance(log, Mapping):
        items = list(log.items())
    else:
        items = [(name, name) for name in (log or [])]
    for name, port in items:
        if isinstance(port, str):
            if not diagram.HasOutputPort(port):
                names = [diagram.get_output_port(i).get_name() for i in range(diagram.num_output_ports())]
                raise ValueError(f"simulate: diagram {diagram.get_name()!r} has no output port {port!r}; "
                                 f"ports: {', '.join(names)}")
            out.append((name, diagram, diagram.GetOutputPort(port)))
        else:
            out.append((name, port.get_system(), port))
    return out


def simulate(diagram: Diagram, context: Context | None, t_final: float, *,
             log: Iterable[str] | Mapping[str, object] = ("state",),
             monitors: Sequence = (), integrator: str = "runge_kutta3", max_step: float = 1e-3,
             accuracy: float = 1e-5, divergence_bound: float = 1e6, t_start: float | None = None,
             fixed_step: bool = False) -> SimulationResult:
    """Simulate ``diagram`` from ``context`` to ``t_final`` [s] with Drake's ``Simulator``.

    Parameters
    ----------
    diagram : Diagram
    context : Context or None
        Initial root context (inputs fixed as needed); None: default context.
    t_final : float
        End time [s].
    log : names or mapping
        Exported output port names of ``diagram`` (or ``{label: OutputPort}`` for
        ports of subsystems) recorded at every step.
    monitors : sequence
        Objects with ``check(root_context) -> str | None`` and ``finish() -> list[Event]``
        (see :func:`rig_monitors`).
    integrator : str
        Drake integrator name (``runge_kutta3`` error-controlled is the default:
        it beats implicit integrators, which finite-difference through Python).
    max_step, accuracy : float
        Maximum step [s] and target accuracy of the integrator.
    divergence_bound : float
        Any state entry beyond this magnitude counts as divergence.
    fixed_step : bool
        Run the integrator at ``max_step`` without error control (e.g. RK3 at
        the 3 kHz control period: several times faster under a sample-and-hold
        controller; check the accuracy against an error-controlled run).
    """
    if not (np.isfinite(t_final) and t_final > 0):
        raise ValueError(f"simulate: t_final = {t_final} must be finite and > 0 [s]")
    if not isinstance(fixed_step, bool):
        raise ValueError(f"simulate: fixed_step = {fixed_step!r} must be True or False "
                         "(the step size is max_step)")
    ports = _resolve_ports(diagram, log)
    sim = Simulator(diagram, context) if context is not None else Simulator(diagram)
    ResetIntegratorFromFlags(sim, integrator, max_step)
    integ = sim.get_mutable_integrator()
    if fixed_step:
        integ.set_fixed_step_mode(True)
    elif integrator not in ("runge_kutta2", "explicit_euler", "semi_explicit_euler"):  # fixed-step ones
        integ.set_target_accuracy(accuracy)
    root = sim.get_mutable_context()
    if t_start is not None:
        if not np.isfinite(t_start):
            raise ValueError(f"simulate: t_start = {t_start} must be finite [s]")
        root.SetTime(t_start)
    if not t_final > root.get_time():  # Drake would end the process (SystemExit) instead of raising
        raise ValueError(f"simulate: t_final = {t_final} s must be after the start time "
                         f"{root.get_time()} s (t_start or the context's time)")
    times: list[float] = []
    rows: dict[str, list] = {name: [] for name, _, _ in ports}
    failure: list[str] = []

    def monitor(ctx: Context):
        x = ctx.get_continuous_state_vector().CopyToVector()
        if not np.all(np.isfinite(x)) or (x.size and np.max(np.abs(x)) > divergence_bound):
            bad = int(np.argmax(~np.isfinite(x) | (np.abs(x) > divergence_bound)))
            failure.append(f"simulation diverged at t = {ctx.get_time():.6g} s: state[{bad}] = {x[bad]}")
            return EventStatus.Failed(diagram, failure[-1])
        times.append(ctx.get_time())
        for name, system, port in ports:
            rows[name].append(np.array(port.Eval(system.GetMyContextFromRoot(ctx)), dtype=float).ravel())
        for m in monitors:
            msg = m.check(ctx)
            if msg:
                failure.append(msg)
                return EventStatus.Failed(diagram, msg)
        return EventStatus.Succeeded()

    for m in monitors:
        if hasattr(m, "reset"):
            m.reset()
    sim.set_monitor(monitor)
    try:
        sim.Initialize()
        sim.AdvanceTo(t_final)
    except RuntimeError as exc:
        if failure and failure[-1].startswith("simulation diverged"):
            raise SimulationDivergedError(failure[-1]) from None
        if failure:
            raise RuntimeError(failure[-1]) from None
        raise
    events = [e for m in monitors for e in m.finish()]
    signals = {k: np.array(v) for k, v in rows.items()}
    return SimulationResult(np.array(times), signals, sorted(events, key=lambda e: e.t_start), sim.get_context())
