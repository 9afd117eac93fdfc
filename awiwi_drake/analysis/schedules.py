"""Input schedules for :func:`~awiwi_drake.analysis.simulate`: steps, ramps, sines, chirps, samples.

A schedule is a pure function of time ``value(t)`` (float or AutoDiffXd; ``t`` relative to the start of the
simulation) in a small frozen dataclass; schedules add (``Step(...) + Sine(...)``) and broadcast to every entry of
the port they drive unless given per entry (:class:`PerEntry`).  :func:`simulate` wires each one in as a Drake
source, :class:`InputSchedule_`, so the integrator sees the signal at every stage.
"""

from __future__ import annotations

import abc
import dataclasses
import math
import sys
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from pydrake.systems.framework import BasicVector_, LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake._math import scalar_value

__all__ = ["Schedule", "Constant", "Step", "Ramp", "Sine", "Chirp", "Samples", "PerEntry", "as_schedule",
           "InputSchedule_", "InputSchedule"]


class Schedule(abc.ABC):
    """Base class: ``value(t)`` for time ``t`` [s] after the start; ``+`` builds a sum."""

    size: int | None = None  # None: broadcast to the port size

    def __post_init__(self):
        """A dataclass schedule's fields must be finite numbers."""
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if not (isinstance(v, (int, float, np.floating)) and not isinstance(v, bool) and math.isfinite(v)):
                raise ValueError(f"{type(self).__name__}: {f.name.rstrip('_')} = {v!r} must be a finite number")

    @abc.abstractmethod
    def value(self, t):
        """The signal at time ``t`` [s] after the start (float or AutoDiffXd ``t``)."""

    def __add__(self, other: "Schedule") -> "Schedule":
        return _Sum((self, as_schedule(other)))

    __radd__ = __add__

    def breakpoints(self) -> tuple:
        """Times of discontinuities (steps) or kinks, for information and plotting."""
        return ()

    def constant(self):
        """The value if the schedule is constant in time (a float, or a vector for :class:`PerEntry`), else None."""
        return None


@dataclass(frozen=True)
class _Sum(Schedule):
    parts: tuple

    def __post_init__(self):      # its fields are schedules, each checked when made
        pass

    def value(self, t):
        out = 0.0
        for p in self.parts:
            out = out + p.value(t)
        return out

    def __add__(self, other):
        return _Sum(self.parts + (as_schedule(other),))

    def breakpoints(self):
        return tuple(sorted({b for p in self.parts for b in p.breakpoints()}))


@dataclass(frozen=True)
class Constant(Schedule):
    """``value`` for all time (unit of the port)."""

    value_: float

    def value(self, t):
        return 0.0 * t + self.value_

    def constant(self):
        return self.value_


@dataclass(frozen=True)
class Step(Schedule):
    """``before`` until ``time`` [s], then ``after``."""

    time: float
    after: float
    before: float = 0.0

    def value(self, t):  # a time within round-off (1e-12 s) of the step is after it
        return 0.0 * t + (self.after if scalar_value(t) >= self.time - 1e-12 * max(1.0, abs(self.time)) else self.before)

    def breakpoints(self):
        return (self.time,)


@dataclass(frozen=True)
class Ramp(Schedule):
    """``start`` until ``t0``, linear to ``end`` at ``t1``, then ``end`` (t0 < t1, seconds)."""

    t0: float
    t1: float
    start: float
    end: float

    def __post_init__(self):
        super().__post_init__()
        if not self.t1 > self.t0:
            raise ValueError(f"Ramp: t1 = {self.t1} must be after t0 = {self.t0} [s]")

    def value(self, t):
        tv = scalar_value(t)
        if tv <= self.t0:
            return 0.0 * t + self.start
        if tv >= self.t1:
            return 0.0 * t + self.end
        return self.start + (self.end - self.start) * (t - self.t0) / (self.t1 - self.t0)

    def breakpoints(self):
        return (self.t0, self.t1)


@dataclass(frozen=True)
class Sine(Schedule):
    """``offset + amplitude sin(2 pi frequency_hz (t - start) + phase)`` for ``t >= start``, else ``offset``."""

    amplitude: float
    frequency_hz: float
    phase: float = 0.0
    offset: float = 0.0
    start: float = 0.0

    def __post_init__(self):
        super().__post_init__()
        if self.frequency_hz <= 0:
            raise ValueError(f"Sine: frequency_hz = {self.frequency_hz} must be > 0 [Hz]")

    def value(self, t):
        if scalar_value(t) < self.start:
            return 0.0 * t + self.offset
        return self.offset + self.amplitude * np.sin(2.0 * math.pi * self.frequency_hz * (t - self.start) + self.phase)


@dataclass(frozen=True)
class Chirp(Schedule):
    """Linear chirp: ``offset + amplitude sin(2 pi (f0 tau + (f1 - f0) tau^2 / (2 duration)))``, ``tau = t - start``.

    Zero (``offset``) before ``start`` and after ``start + duration``; the
    instantaneous frequency rises linearly from ``f0`` to ``f1`` [Hz] (Fig 11.4's sweep).
    """

    amplitude: float
    f0: float
    f1: float
    duration: float
    offset: float = 0.0
    start: float = 0.0

    def __post_init__(self):
        super().__post_init__()
        if self.f0 < 0 or self.f1 <= 0 or self.duration <= 0:
            raise ValueError(f"Chirp: need f0 >= 0, f1 > 0 [Hz] and duration > 0 [s], got "
                             f"f0 = {self.f0}, f1 = {self.f1}, duration = {self.duration}")

    def value(self, t):
        tau = scalar_value(t) - self.start
        if tau < 0 or tau > self.duration:
            return 0.0 * t + self.offset
        tt = t - self.start
        k = (self.f1 - self.f0) / self.duration
        return self.offset + self.amplitude * np.sin(2.0 * math.pi * (self.f0 * tt + 0.5 * k * tt * tt))

    def breakpoints(self):
        return (self.start, self.start + self.duration)


@dataclass(frozen=True)
class Samples(Schedule):
    """Recorded samples ``values[i]`` at ``times[i]`` (increasing), held (``"zoh"``) or interpolated (``"linear"``).

    A time within 1e-9 of the first sample spacing before a sample counts as that sample (round-off).

    ``values`` is ``(N,)`` (broadcast) or ``(N, size)`` (one column per port entry).
    Before the first and after the last sample the end values are held.
    """

    times: tuple
    values: tuple
    hold: str = "zoh"

    def __init__(self, times: Sequence[float], values, hold: str = "zoh"):
        t = np.asarray(times, dtype=float).reshape(-1)
        v = np.asarray(values, dtype=float)
        if v.ndim == 1:
            v = v[:, None]
        if v.ndim != 2 or v.shape[0] != t.size or t.size == 0:
            raise ValueError(f"Samples: values must have one row per time ({t.size} times), got shape {np.shape(values)}")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v))):
            raise ValueError("Samples: times and values must be finite")
        if np.any(np.diff(t) <= 0):
            raise ValueError("Samples: times must be strictly increasing")
        if hold not in ("zoh", "linear"):
            raise ValueError(f"Samples: hold = {hold!r} must be 'zoh' or 'linear'")
        object.__setattr__(self, "times", t)
        object.__setattr__(self, "values", v)
        object.__setattr__(self, "hold", hold)
        object.__setattr__(self, "size", None if v.shape[1] == 1 else v.shape[1])

    def __hash__(self):
        return id(self)

    def value(self, t):
        tv = scalar_value(t)
        tol = 1e-9 * (self.times[1] - self.times[0]) if len(self.times) > 1 else 1e-12  # round-off of a sample time
        i = int(np.searchsorted(self.times, tv + tol, side="right")) - 1
        if i < 0:
            row = self.values[0]
        elif i >= len(self.times) - 1 or self.hold == "zoh":
            row = self.values[min(i, len(self.times) - 1)]
        else:
            t0, t1 = self.times[i], self.times[i + 1]
            w = (t - t0) / (t1 - t0)
            row = self.values[i] + (self.values[i + 1] - self.values[i]) * w
            return row if self.size is not None else row[0]
        return (0.0 * t + row) if self.size is not None else 0.0 * t + row[0]


@dataclass(frozen=True)
class PerEntry(Schedule):
    """One schedule per entry of a vector port (e.g. a step on motor 1, a constant on motor 2)."""

    entries: tuple

    def __init__(self, entries: Sequence):
        object.__setattr__(self, "entries", tuple(as_schedule(e) for e in entries))
        if not self.entries:
            raise ValueError("PerEntry: needs at least one entry")
        object.__setattr__(self, "size", len(self.entries))

    def value(self, t):
        return np.array([e.value(t) for e in self.entries], dtype=object if not isinstance(t, float) else float)

    def breakpoints(self):
        return tuple(sorted({b for e in self.entries for b in e.breakpoints()}))

    def constant(self):
        values = [e.constant() for e in self.entries]
        return None if any(v is None or np.ndim(v) for v in values) else np.array(values, float)


def as_schedule(s) -> Schedule:
    """A :class:`Schedule` from a schedule, a number (:class:`Constant`) or a vector (constant per entry)."""
    if isinstance(s, Schedule):
        return s
    if isinstance(s, bool):
        raise ValueError(f"input schedule: {s!r} is a bool, not a number or a Schedule")
    if isinstance(s, (int, float, np.floating, np.integer)):
        return Constant(float(s))
    try:
        arr = np.asarray(s, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"input schedule: {s!r} is neither a Schedule, a number nor a vector of numbers") from None
    return PerEntry([Constant(float(v)) for v in arr])


@TemplateSystem.define("InputSchedule_", scope=sys.modules[__name__])
def InputSchedule_(T):
    """A source whose output ``value`` (size ``size``) is ``schedule.value(t - t0)``.

    Output prerequisites: time only (no state, no input), so the source never
    creates an algebraic loop and Drake re-evaluates it only when time changes.
    """

    class Impl(LeafSystem_[T]):
        def _construct(self, schedule: Schedule, size: int, t0: float = 0.0, converter=None):
            LeafSystem_[T].__init__(self, converter)
            schedule = as_schedule(schedule)
            if schedule.size is not None and schedule.size != int(size):
                raise ValueError(f"InputSchedule: schedule has {schedule.size} entries but the port has {size}")
            self.schedule, self.size, self.t0 = schedule, int(size), float(t0)
            self.DeclareVectorOutputPort("value", int(size), self._calc,
                                         prerequisites_of_calc={self.time_ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.schedule, other.size, other.t0, converter=converter)

        def _calc(self, context, output: BasicVector_[T]):
            t = context.get_time() - self.t0
            v = self.schedule.value(t)
            if np.ndim(v) == 0:
                output.SetFromVector(np.full(self.size, v, dtype=object if T != float else float))
            else:
                output.SetFromVector(np.asarray(v))

    return Impl


InputSchedule = InputSchedule_[None]
