"""Health monitors for :func:`~awiwi_drake.analysis.simulate`: slack, saturation, spring over-range.

A monitor names a port (an output port, or an input port whose driving signal is then watched) and a condition on
its value.  :func:`simulate` logs the port with Drake's C++ ``VectorLogSink`` and evaluates the condition on the
logged samples with numpy once per progress chunk (nothing in Python per step); a condition that holds on
consecutive samples is one :class:`Event` interval.  Divergence is not a monitor: :func:`simulate` checks the state
itself and raises :class:`~awiwi_drake.analysis.simulate.SimulationDivergedError`.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import Sequence

import numpy as np

__all__ = ["Event", "Monitor", "SlackMonitor", "SaturationMonitor", "OverrangeMonitor", "PairSlackMonitor",
           "rig_monitors", "find_events"]


@dataclass
class Event:
    """An interval during which a condition held for one channel.

    ``t_start`` and ``t_end`` are the first and last logged sample times at
    which it held (within one log period of the true crossing), ``extreme`` the
    most extreme logged value.
    """

    kind: str
    channel: str
    t_start: float
    t_end: float
    extreme: float

    def __str__(self) -> str:
        return f"{self.kind} on {self.channel} from {self.t_start:.4g} s to {self.t_end:.4g} s (extreme {self.extreme:.4g})"

    def to_json(self) -> dict:
        return dict(kind=self.kind, channel=self.channel, t_start=self.t_start, t_end=self.t_end,
                    extreme=self.extreme)


class Monitor(abc.ABC):
    """A condition on one port, checked on logged samples: ``port_name`` (an output port, or an input port: its
    driving signal is watched) of ``system`` (the simulated diagram or one of its subsystems; None: the simulated
    diagram), channel ``labels`` (default ``port[i]``); ``raise_on_event``: stop the run
    (``SimulationEventError``) at the first chunk where the condition held."""

    kind = "condition"
    direction = "max"   # which extreme is reported: "max", "min" or "abs"

    def __init__(self, system, port_name: str, labels: Sequence[str] | None = None, raise_on_event: bool = False):
        self.system, self.port_name = system, port_name
        self.labels = list(labels) if labels is not None else None
        self.raise_on_event = bool(raise_on_event)

    @abc.abstractmethod
    def condition(self, v: np.ndarray) -> np.ndarray:
        """Boolean ``(T, k)``: does the condition hold at each logged sample and channel?"""

    def channels(self, v: np.ndarray) -> np.ndarray:
        """The watched quantity ``(T, k)`` from the logged port value ``(T, size)``."""
        return v

    def label(self, i: int) -> str:
        return self.labels[i] if self.labels else f"{self.port_name}[{i}]"

    def limits(self) -> list[tuple[str, float]]:
        """Thresholds on the watched port's own values, for plots: ``[(description, value), ...]``."""
        return []

    #: label of the logged signal the limits belong to (None: the watched port's own log)
    limits_on = None

    def events(self, t: np.ndarray, v: np.ndarray) -> list[Event]:
        """Intervals of consecutive samples where the condition holds (vectorised)."""
        c = self.channels(np.asarray(v, float).reshape(len(t), -1))
        return find_events(self.kind, [self.label(i) for i in range(c.shape[1])], t, c, self.condition(c),
                           self.direction)


def find_events(kind: str, labels: Sequence[str], t: np.ndarray, values: np.ndarray, hit: np.ndarray,
                direction: str = "max") -> list[Event]:
    """One :class:`Event` per run of ``True`` in each column of ``hit`` (shape ``(T, k)``)."""
    out = []
    if len(t) == 0:
        return out
    for j in range(hit.shape[1]):
        h = hit[:, j].astype(np.int8)
        if not h.any():
            continue
        edges = np.diff(np.concatenate([[0], h, [0]]))
        starts, ends = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0] - 1
        for s, e in zip(starts, ends):
            seg = values[s:e + 1, j]
            if direction == "min":
                ext = float(np.min(seg))
            elif direction == "abs":
                ext = float(seg[int(np.argmax(np.abs(seg)))])
            else:
                ext = float(np.max(seg))
            out.append(Event(kind, labels[j], float(t[s]), float(t[e]), ext))
    return out


class _ForceMonitor(Monitor):
    """A condition on tendon forces: the ``tendon_force`` port, or (``of_state``) the forces computed
    with numpy from the logged ``state`` after each chunk, so no force is evaluated per step.

    ``of_state(states (T, n)) -> forces (T, m)`` must be the law behind the ``tendon_force`` port
    (e.g. :attr:`awiwi_drake.rigs.base.Rig.tendon_force_of_state`).
    """

    def __init__(self, system=None, port_name: str = "tendon_force", of_state=None, **kw):
        self.of_state = of_state
        if of_state is not None:
            port_name = "state"
        super().__init__(system, port_name, **kw)

    def channels(self, v):
        return v if self.of_state is None else np.asarray(self.of_state(v), float).reshape(len(v), -1)

    def label(self, i: int) -> str:
        return self.labels[i] if self.labels else f"tendon_force[{i}]"

    @property
    def limits_on(self):
        """The logged signal the limits are drawn on (``tendon_force``, not the watched ``state``)."""
        return "tendon_force" if self.of_state is not None else None


class SlackMonitor(_ForceMonitor):
    """Tendon slack: the force on ``port_name`` at or below ``slack_force`` [N]."""

    kind = "tendon_slack"
    direction = "min"

    def __init__(self, system=None, port_name: str = "tendon_force", slack_force: float = 0.0, **kw):
        super().__init__(system, port_name, **kw)
        self.slack_force = float(slack_force)

    def condition(self, v):
        return v <= self.slack_force

    def limits(self):
        return [("slack (tendon force <= %g N)" % self.slack_force, self.slack_force)]


class OverrangeMonitor(_ForceMonitor):
    """Spring beyond its calibrated range: force on ``port_name`` above ``max_force`` [N]."""

    kind = "spring_overrange"

    def __init__(self, system=None, max_force: float = np.inf, port_name: str = "tendon_force", **kw):
        super().__init__(system, port_name, **kw)
        self.max_force = float(max_force)

    def condition(self, v):
        return v > self.max_force

    def limits(self):
        return [("spring calibrated range %g N" % self.max_force, self.max_force)]


class SaturationMonitor(Monitor):
    """Actuator saturation: ``|commanded torque| >= torque_limit`` [Nm] on ``port_name`` (input or output)."""

    kind = "actuator_saturation"
    direction = "abs"

    def __init__(self, system=None, torque_limit: float = np.inf, port_name: str = "motor_torque", **kw):
        super().__init__(system, port_name, **kw)
        self.torque_limit = float(torque_limit)

    def condition(self, v):
        return np.abs(v) >= self.torque_limit

    def limits(self):
        return [("torque limit +-%g Nm" % self.torque_limit, self.torque_limit),
                ("torque limit +-%g Nm" % self.torque_limit, -self.torque_limit)]


class PairSlackMonitor(Monitor):
    """Slack in an antagonistic torsional spring ``phi(d)`` (flexible joint, nonlinear spring).

    The pair's tendons have elongations ``x0 + r d`` and ``x0 - r d`` with
    ``d = theta - q`` (entries ``i_theta`` and ``i_q`` of the ``state`` output);
    a tendon is slack when its elongation is <= 0.
    """

    kind = "tendon_slack"
    direction = "min"

    def __init__(self, system=None, x0: float = 0.0, radius: float = 1.0, i_q: int = 0, i_theta: int = 2, **kw):
        kw.setdefault("labels", ["pair tendon 1", "pair tendon 2"])
        super().__init__(system, "state", **kw)
        self.x0, self.r, self.i_q, self.i_theta = float(x0), float(radius), int(i_q), int(i_theta)

    def channels(self, v):
        d = v[:, self.i_theta] - v[:, self.i_q]
        return np.column_stack([self.x0 + self.r * d, self.x0 - self.r * d])

    def condition(self, v):
        return v <= 0.0


def rig_monitors(rig, *, raise_on_slack: bool = False, raise_on_saturation: bool = False) -> list[Monitor]:
    """Slack, over-range and saturation monitors for a rig (its ports, wherever the rig sits in a diagram).

    The rig's fields say what applies: ``tension_only`` (slack on ``tendon_force``, computed from the
    logged ``state`` with ``tendon_force_of_state`` when the rig has it),
    ``pair_slack`` (slack of the two hidden tendons of an antagonistic torsional
    spring, from the ``state`` output), ``max_force`` (calibrated spring range)
    and ``torque_limit`` (on the rig's ``motor_torque`` input).
    """
    d = rig.diagram
    monitors: list[Monitor] = []
    # forces from the logged state (numpy, once per chunk) where the rig gives their law
    of_state = getattr(rig, "tendon_force_of_state", None)
    if rig.tension_only and d.HasOutputPort("tendon_force"):
        monitors.append(SlackMonitor(d, of_state=of_state, raise_on_event=raise_on_slack))
    if rig.pair_slack is not None:
        x0, r = rig.pair_slack
        monitors.append(PairSlackMonitor(d, x0, r, raise_on_event=raise_on_slack))
    if rig.max_force is not None and d.HasOutputPort("tendon_force"):
        monitors.append(OverrangeMonitor(d, rig.max_force, of_state=of_state))
    limit = rig.torque_limit
    if limit is not None:
        monitors.append(SaturationMonitor(d, limit, raise_on_event=raise_on_saturation))
    return monitors
