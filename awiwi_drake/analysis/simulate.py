"""The one simulation entry point: :func:`simulate` (Drake's ``Simulator`` on any diagram).

The simulated diagram is a copy of the one given, flattened (:func:`add_flat`: every leaf cloned by scalar
conversion, no nested diagrams, each of which costs Drake's simulator ~1 us per step), with the input schedules as
Drake sources (:mod:`~awiwi_drake.analysis.schedules`) and the logged and monitored ports as Drake's C++
``VectorLogSink``: no Python runs per step.  Divergence (non-finite or exploding state) and the monitors
(:mod:`~awiwi_drake.analysis.monitors`: slack, saturation, spring over-range) are checked on the logs at about 40
chunk boundaries, where ``progress(t, duration)`` is also called.  The user's diagram can be simulated again or
embedded elsewhere; the given context is advanced to the end time like ``Simulator`` would, and is returned as
``final_context``.

A *sampled plant* (Drake's ``DiscreteTimeApproximation``, e.g. a single-joint rig in a sampled loop, see
:func:`~awiwi_drake.control.closed_loop`) integrates itself with fixed-step RK3 at the control period inside its
discrete update: such a loop runs one discrete update per period, error control, another integrator or a shorter step
are refused for it (build the loop with ``sampled_rig=False`` for those), its state between two sample instants is the
next instant's (log it on its grid), and a ``t_final`` within round-off of a sample instant is snapped onto it.
"""

from __future__ import annotations

import math
import time
import warnings
from fractions import Fraction
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np
from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
from pydrake.systems.framework import (Context, Diagram, DiagramBuilder, InputPort, InputPortIndex, OutputPort,
                                       OutputPortIndex, PortDataType, System)
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput

from awiwi_drake.analysis.monitors import Monitor
from awiwi_drake.components.rig_system import SAMPLED_INTEGRATOR as _SAMPLED_SCHEME
from awiwi_drake.analysis.results import SimulationResult, unit
from awiwi_drake.analysis.schedules import InputSchedule, as_schedule
from awiwi_drake.analysis.monitors import Event
from awiwi_drake.parameters.control import FIXED_STEP_CHECK_INTERVAL, FIXED_STEP_STABILITY_MARGIN

__all__ = ["SimulationError", "SimulationDivergedError", "SimulationEventError", "InfeasibleForceError",
           "PHYSICAL_FAILURES", "simulate", "MODES", "control_period", "sampled_plants", "FlatSystem", "add_flat",
           "stability_function", "fixed_step_substeps"]

MODES = ("auto", "fixed_step", "error_controlled")
_FIXED_STEP_INTEGRATORS = ("explicit_euler", "semi_explicit_euler", "runge_kutta2")
_CHUNKS = 40  # divergence/monitor/progress checks per run


class SimulationError(RuntimeError):
    """A simulation could not be run or completed (bad times, Drake refused, integrator failure)."""


class SimulationDivergedError(SimulationError):
    """The state became non-finite or exceeded the divergence bound (``t``: when it was seen [s])."""

    status = "diverged"

    def __init__(self, message: str, t: float = float("nan")):
        super().__init__(message)
        self.t = float(t)


class SimulationEventError(SimulationError):
    """A monitor created with ``raise_on_event=True`` saw its condition (``status``: the event's kind,
    e.g. ``actuator_saturation``; ``t``: its start [s])."""

    def __init__(self, message: str, kind: str = "event", t: float = float("nan")):
        super().__init__(message)
        self.status, self.t = kind, float(t)


class InfeasibleForceError(ValueError):
    """A tendon force law was asked for a force it cannot produce (a negative or beyond-range tendon force,
    e.g. from an infeasible force distribution: a tendon would have to push).  :func:`simulate` sets ``t``
    to the simulated time at which it was raised [s]."""

    status = "infeasible_force"
    t = float("nan")


# the package's own physical failures that stop a simulation (status names the cause, t the time):
# studies that run many cases record them per case and go on; anything else is a programming error
PHYSICAL_FAILURES = (SimulationDivergedError, SimulationEventError, InfeasibleForceError)


_MAX_RATE_RATIO = 1000  # a common period this many times below the shortest one: rates not commensurate
SAMPLED_PLANT_PREFIX = "DiscreteTimeApproximated_"   # Drake's name of a DiscreteTimeApproximation of <name>
_GRID_TOLERANCE = 1e-6   # periods: a time this close to a sample instant is that instant (decimal inputs' round-off)


#: order p of the fixed-step integrators whose stability function is the degree-p Taylor polynomial of exp
#: (explicit p-stage methods of order p <= 4: R(z) = sum_{k<=p} z^k / k!; Drake's RK2 is Heun's method, RK3 a
#: 3-stage 3rd-order method)
_TAYLOR_ORDER = {"explicit_euler": 1, "runge_kutta2": 2, "runge_kutta3": 3}
_MAX_SUBSTEPS = 64


def stability_function(integrator: str, z) -> np.ndarray:
    """``|R(z)|``, the fixed-step ``integrator``'s amplification of the mode ``exp(lambda t)`` over one step
    (``z = h lambda``); R is the Taylor polynomial of ``exp`` of the method's order (:data:`_TAYLOR_ORDER`)."""
    z = np.asarray(z, dtype=complex)
    terms, r = np.ones_like(z), np.ones_like(z)
    for k in range(1, _TAYLOR_ORDER[integrator] + 1):
        terms = terms * z / k
        r = r + terms
    return np.abs(r)


def _excess(integrator: str, z) -> np.ndarray:
    """``|R(z)| - max(1, |exp(z)|)`` per mode: > 0 where the integrator amplifies a mode that the continuous
    system does not (numerical instability); modes the system itself grows are judged against their growth."""
    z = np.asarray(z, dtype=complex)
    return stability_function(integrator, z) - np.maximum(1.0, np.abs(np.exp(z)))


def fixed_step_substeps(modes, h: float, integrator: str = "runge_kutta3",
                        margin: float = FIXED_STEP_STABILITY_MARGIN) -> tuple[int, complex, float]:
    """``(k, worst mode, |R(h lambda)|)``: ``k = 1`` when every mode ``lambda`` [1/s] lies in ``integrator``'s
    stability region at the step ``h`` [s], else the smallest ``k`` for which every ``margin h lambda / k`` does
    (0 when none up to 64 does); the mode reported is the one furthest outside at ``h`` (all inside: the fastest)."""
    modes = np.asarray(modes, dtype=complex).reshape(-1)
    if modes.size == 0:
        return 1, complex("nan"), float("nan")
    excess = _excess(integrator, h * modes)
    i = int(np.argmax(excess))
    if excess[i] <= 1e-9:                 # all inside: report the fastest mode
        i = int(np.argmax(np.abs(modes)))
        return 1, complex(modes[i]), float(stability_function(integrator, h * modes[i]))
    growth = float(stability_function(integrator, h * modes[i]))
    for k in range(2, _MAX_SUBSTEPS + 1):
        if np.all(_excess(integrator, margin * h * modes / k) <= 1e-9):
            return k, complex(modes[i]), growth
    return 0, complex(modes[i]), growth


def _plant_modes(sub: "FlatSystem", root) -> list[tuple[str, np.ndarray]]:
    """``(leaf name, modes)`` of every leaf copy in ``sub`` that reports its modes (``integration_modes``)."""
    return [(leaf.get_name(), np.asarray(copy.integration_modes(copy.GetMyContextFromRoot(root))))
            for leaf, copy in sub.leaves
            if callable(getattr(copy, "integration_modes", None)) and copy.num_continuous_states()]


def _mode_text(lam: complex) -> str:
    return f"{lam.real:.4g} {'+' if lam.imag >= 0 else '-'} {abs(lam.imag):.4g}j 1/s"


def sampled_plants(system: System) -> list[System]:
    """The leaf systems under ``system`` that are Drake ``DiscreteTimeApproximation`` s of a continuous
    system (named ``DiscreteTimeApproximated_<name>`` by Drake): continuous plants integrated inside a
    discrete update, whose discrete state is the plant's state."""
    if isinstance(system, Diagram):
        return [p for s in system.GetSystems() for p in sampled_plants(s)]
    return [system] if system.get_name().startswith(SAMPLED_PLANT_PREFIX) else []


class FlatSystem:
    """``system``'s leaves copied into a ``DiagramBuilder`` and connected as in ``system`` (:func:`add_flat`).

    ``inputs[i]``: the copies' input ports that ``system``'s input ``i`` feeds (a list: one exported input may
    feed several leaves); ``outputs[j]``: the copy's output port behind ``system``'s output ``j``; ``leaves``:
    ``(original leaf, copy)`` pairs in the order of ``system``'s state (its subsystems depth-first).
    """

    def __init__(self, system: System, inputs: list, outputs: list, leaves: list):
        self.system, self.inputs, self.outputs, self.leaves = system, inputs, outputs, leaves

    def GetInputPort(self, name: str) -> list:
        return self.inputs[self.system.GetInputPort(name).get_index()]

    def GetOutputPort(self, name: str):
        return self.outputs[self.system.GetOutputPort(name).get_index()]

    def copy_states_from(self, context: Context, root: Context) -> None:
        """Each copy's state and parameters in ``root`` (the builder's diagram's context) from its original's
        in ``context`` (a context of ``system``)."""
        for leaf, copy in self.leaves:
            copy.GetMyMutableContextFromRoot(root).SetStateAndParametersFrom(leaf.GetMyContextFromRoot(context))

    def copy_states_to(self, context: Context, root: Context) -> None:
        """The reverse of :meth:`copy_states_from`, and ``root``'s time into ``context``."""
        for leaf, copy in self.leaves:
            leaf.GetMyMutableContextFromRoot(context).SetStateAndParametersFrom(copy.GetMyContextFromRoot(root))
        context.SetTime(root.get_time())


def add_flat(builder: DiagramBuilder, system: System, name: str) -> FlatSystem:
    """Copies (scalar conversion: ``Clone``, or a ``TemplateSystem``'s copy constructor) of the leaf systems of
    ``system`` (a leaf or a diagram, nested
    diagrams included) added to ``builder`` and connected as in ``system``, without any sub-diagram (a nested
    diagram costs Drake's simulator ~1 us per step, measured on the joint-rig loop). A leaf copy is named
    by its path below ``name`` (``name.<subsystem>.<leaf>``; ``system`` itself a leaf: ``name``). Raises
    ``RuntimeError`` when a leaf does not support scalar conversion."""
    leaves: list = []

    def add(s: System, path: str):
        if not isinstance(s, Diagram):
            # a Python TemplateSystem copies itself (its _construct_copy, float to float); Drake's Clone() goes
            # through AutoDiffXd and back, two constructions (measured: the index finger's fused chain 2.1 ms
            # against 0.16, its links-and-drive system 0.37 against 0.09)
            c = type(s)(s) if getattr(type(s), "_construct_copy", None) is not None else s.Clone()
            c.set_name(path)
            builder.AddSystem(c)
            leaves.append((s, c))
            return ([[c.get_input_port(i)] for i in range(s.num_input_ports())],
                    [c.get_output_port(j) for j in range(s.num_output_ports())])
        parts = {id(sub): add(sub, f"{path}.{sub.get_name()}") for sub in s.GetSystems()}
        for (dst, i), (src, j) in s.connection_map().items():
            for port in parts[id(dst)][0][i]:
                builder.Connect(parts[id(src)][1][j], port)
        ins = [[port for sub, i in s.GetInputPortLocators(InputPortIndex(k)) for port in parts[id(sub)][0][i]]
               for k in range(s.num_input_ports())]
        outs = []
        for k in range(s.num_output_ports()):
            sub, j = s.get_output_port_locator(OutputPortIndex(k))
            outs.append(parts[id(sub)][1][j])
        return ins, outs

    inputs, outputs = add(system, name)
    return FlatSystem(system, inputs, outputs, leaves)


def _sampled_plant_state(plant: System, context) -> np.ndarray:
    """A sampled plant's state in the plant's own coordinates: its first output when that is as long as its
    discrete state (the single-joint rigs integrate in other coordinates and output the physical state,
    :func:`~awiwi_drake.components.rig_system.rig_integration_system`), else the discrete state itself."""
    n = context.get_discrete_state(0).size()
    if plant.num_output_ports() and plant.get_output_port(0).size() == n:
        return np.array(plant.get_output_port(0).Eval(context), dtype=float).reshape(-1)
    return context.get_discrete_state(0).CopyToVector()


def _export(builder, ports: list, name: str) -> None:
    """Export ``ports`` (the copies' inputs behind one input of the flattened system) as one input ``name``."""
    builder.ExportInput(ports[0], name)
    for port in ports[1:]:
        builder.ConnectInput(name, port)


def _leaf_timings(system: System) -> list[tuple[float, float]]:
    """``(period, offset)`` of every leaf system's unique periodic discrete update under ``system``."""
    if isinstance(system, Diagram):
        return [pt for s in system.GetSystems() for pt in _leaf_timings(s)]
    attr = system.GetUniquePeriodicDiscreteUpdateAttribute()
    return [] if attr is None else [(float(attr.period_sec()), float(attr.offset_sec()))]


def control_period(diagram: System) -> float | None:
    """The sampled loop's fixed step [s]: the common period of its periodic discrete updates, else None.

    One rate (e.g. a 3 kHz zero-order hold): that period.  Several (e.g. a 6 kHz law with the 3 kHz
    tendon-length estimator of the hand): their greatest common divisor (periods and offsets as
    fractions, so 1/6000 and 1/3000 give 1/6000), the longest step on which every sample instant
    falls.  None when there is no periodic discrete update, or the rates are not commensurate (the
    common period would be over 1000x shorter than the shortest one).
    """
    attr = diagram.GetUniquePeriodicDiscreteUpdateAttribute()
    if attr is not None and attr.offset_sec() == 0.0:
        return float(attr.period_sec())
    times = [v for pt in _leaf_timings(diagram) for v in pt if v > 0.0]
    if not times:
        return None
    fr = [Fraction(v).limit_denominator(10 ** 12) for v in times]
    den = math.lcm(*(f.denominator for f in fr))
    common = math.gcd(*(f.numerator * (den // f.denominator) for f in fr)) / den
    if common < min(times) / _MAX_RATE_RATIO or any(abs(v / common - round(v / common)) > 1e-9 * v / common
                                                     for v in times):
        return None
    return float(common)


def _unwrap(system) -> tuple[System, tuple]:
    """``(diagram, state_names)`` from a System or a handle with ``diagram`` (Rig, ClosedLoop, ...)."""
    if isinstance(system, System):
        return system, ()
    diagram = getattr(system, "diagram", None)
    if not isinstance(diagram, System):
        raise ValueError(f"simulate: expected a Drake System or an object with a 'diagram' (Rig, ClosedLoop), "
                         f"got {type(system).__name__}")
    names = getattr(system, "state_names", None)
    if names is None and getattr(system, "rig", None) is not None:
        names = getattr(system.rig, "state_names", None)
    return diagram, tuple(names or ())


def _port_names(ports_of: Callable[[int], Any], n: int) -> list[str]:
    return [ports_of(i).get_name() for i in range(n)]


def _path(root: System, target: System) -> list[str] | None:
    """Subsystem names from ``root`` down to ``target`` ([] for the root itself), or None."""
    if target is root:
        return []
    if isinstance(root, Diagram):
        for s in root.GetSystems():
            sub = _path(s, target)
            if sub is not None:
                return [s.get_name()] + sub
    return None


def simulate(system, context: Context | None, t_final: float, *,
             inputs: Mapping[str, Any] | None = None,
             log: Iterable[str] | Mapping[str, Any] | None = None,
             monitors: Sequence[Monitor] = (), mode: str = "auto", step: float | None = None,
             integrator: str = "runge_kutta3", max_step: float = 1e-3, accuracy: float = 1e-5,
             divergence_bound: float = 1e6, t_start: float | None = None, log_period: float | None = None,
             progress: Callable[[float, float], Any] | None = None,
             state_names: Sequence[str] | None = None, substeps: int | None = None) -> SimulationResult:
    """Simulate ``system`` (a Diagram or System, or an object with a ``diagram``: Rig, ClosedLoop, finger/hand
    handle) from ``context`` (state set, inputs fixed as needed; None: its default context; advanced to ``t_final``
    like ``Simulator`` does) to the absolute time ``t_final`` [s] with Drake's ``Simulator``; a
    :class:`SimulationResult`.

    ``inputs``: port name -> schedule, number or vector: input ports driven by a signal instead of their fixed value
    (:class:`~awiwi_drake.analysis.schedules.Step`, ``Ramp``, ``Sine``, ``Chirp``, ``Samples``, ``PerEntry``, sums;
    times relative to the start).  ``log``: the ports recorded, names of output ports (or input ports: their driving
    signal) of ``system``, or ``{label: port}`` with ports of subsystems (default ``("state",)`` when the diagram has
    a ``state`` output), every integrator step or every ``log_period`` [s].  ``monitors``: slack / saturation /
    over-range monitors (:func:`~awiwi_drake.analysis.rig_monitors`).  ``state_names``: channel names of the
    ``state`` output (default: the handle's).  ``t_start`` [s]: default the context's time.  ``progress(t,
    duration)``: simulated seconds since the start, called about 40 times per run (and at the end).  A state entry
    beyond ``divergence_bound`` in magnitude counts as divergence.

    ``mode`` (one of :data:`MODES`): ``auto`` integrates with a fixed step at the control period for sampled loops
    (the common period of the diagram's periodic discrete updates, :func:`control_period`) and error-controlled
    otherwise (``max_step`` [s], target ``accuracy``).  ``step`` [s]: the fixed step, default the control period (or
    ``max_step`` for a continuous diagram); for a sampled loop it must divide the control period.  ``integrator``:
    Drake's name (``runge_kutta3`` default: for the hand at its operating point the cheapest stable fixed-step choice
    at 3 kHz; ``runge_kutta2`` diverges there).

    ``substeps`` (fixed step only): integrate at ``step / substeps``.  Before a fixed-step ``explicit_euler``,
    ``runge_kutta2`` or ``runge_kutta3`` run, every leaf with an ``integration_modes(context)`` hook (the finger/hand
    plant: the eigenvalues of its dynamics' Jacobian with its inputs held, from central differences of its compiled
    laws checked against Drake's ``Linearize``, or ``Linearize`` itself without kernels) has each mode ``lambda``
    tested against the integrator's stability function ``R`` (:func:`stability_function`) at ``z = h lambda``.  A
    mode the integrator amplifies beyond the continuous system (``|R| > max(1, |exp(z)|)``) makes None (default)
    integrate at ``h / k``, the smallest ``k`` that puts every mode inside with the margin
    ``parameters.control.FIXED_STEP_STABILITY_MARGIN`` (substeps of the control period: the loop's sampling is
    unchanged), with a warning and ``info["substeps"]`` / ``info["fastest_mode"]``; ``1`` refuses such a run (a
    ``ValueError`` naming the mode and ``|R|``), ``k`` imposes ``k``.  The check is repeated during the run, at the
    first progress-chunk boundary at least ``parameters.control.FIXED_STEP_CHECK_INTERVAL`` simulated seconds after
    the last one, and at the end state: a mode outside the region at the step taken is an ``integrator_instability``
    event from the first to the last check that found it outside (``extreme`` the largest ``|R|``), with a warning;
    ``info["stability_checks"]`` lists the checked times (the same on every machine; an excursion between two checks
    is missed).

    Raises ``ValueError`` for a bad argument (naming the argument, port or value), ``SimulationDivergedError`` for a
    non-finite or exploding state (naming the time and the state entry), ``SimulationEventError`` when a monitor with
    ``raise_on_event=True`` saw its condition, ``SimulationError`` when Drake could not complete the run (its message
    included).
    """
    diagram, names_from_handle = _unwrap(system)
    state_names = tuple(state_names) if state_names is not None else names_from_handle
    if mode not in MODES:
        raise ValueError(f"simulate: mode = {mode!r} must be one of {', '.join(MODES)}")
    for label, v, positive in (("t_final", t_final, False), ("max_step", max_step, True), ("accuracy", accuracy, True),
                               ("divergence_bound", divergence_bound, True), ("step", step, True),
                               ("log_period", log_period, True), ("t_start", t_start, False)):
        if (v is not None or label == "t_final") and (
                isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or not math.isfinite(v)
                or (positive and v <= 0)):
            raise ValueError(f"simulate: {label} = {v!r} must be a finite number" + (" > 0" if positive else ""))
    if substeps is not None and (isinstance(substeps, bool) or not isinstance(substeps, (int, np.integer))
                                 or substeps < 1):
        raise ValueError(f"simulate: substeps = {substeps!r} must be a positive integer")
    user_ctx = context if context is not None else diagram.CreateDefaultContext()
    start = float(user_ctx.get_time() if t_start is None else t_start)
    if not float(t_final) > start:
        raise ValueError(f"simulate: t_final = {t_final} s must be after the start time {start} s")
    duration = float(t_final) - start

    # -- integration mode ---------------------------------------------------
    period = control_period(diagram)
    sampled = sampled_plants(diagram)
    if sampled and (mode == "error_controlled" or (step is not None and abs(float(step) - period) > 1e-12 * period)
                    or integrator != _SAMPLED_SCHEME):
        what = (f"mode = {mode!r}" if mode == "error_controlled" else f"integrator = {integrator!r}"
                if integrator != _SAMPLED_SCHEME else f"step = {step!r} s")
        raise ValueError(f"simulate: {what}: diagram {diagram.get_name()!r} holds a sampled plant "
                         f"({sampled[0].get_name()!r}, fixed-step RK3 at the control period {period:g} s inside "
                         f"its discrete update); build the loop with closed_loop(..., sampled_rig=False) to "
                         f"integrate the rig otherwise")
    if sampled:
        # a sampled plant's state after the update at t_n is already x(t_n+1): an end time within round-off of a
        # sample instant (0.05 s at 3 kHz) is that instant as Drake computes it (k * period), not one ulp past it
        n = float(t_final) / period
        if abs(n - round(n)) <= _GRID_TOLERANCE:
            t_final = round(n) * period
            duration = t_final - start
    if mode == "auto":
        mode = "fixed_step" if (period is not None or integrator in _FIXED_STEP_INTEGRATORS) else "error_controlled"
    if mode == "fixed_step":
        h = float(step) if step is not None else (period if period is not None else float(max_step))
        if period is not None:
            ratio = period / h
            if abs(ratio - round(ratio)) > 1e-9 * max(1.0, ratio) or round(ratio) < 1:
                raise ValueError(f"simulate: step = {h:g} s must be the control period {period:g} s or a divisor of it")
    else:
        if integrator in _FIXED_STEP_INTEGRATORS:
            raise ValueError(f"simulate: integrator {integrator!r} has no error control; use mode='fixed_step'")
        h = float(max_step)

    # -- a flat copy with sources and sinks -----------------------------------
    b = DiagramBuilder()
    try:
        sub = add_flat(b, diagram, "simulated")
    except RuntimeError as exc:
        raise ValueError(f"simulate: diagram {diagram.get_name()!r} cannot be cloned (every subsystem must "
                         f"support scalar conversion): {exc}") from None
    inputs = dict(inputs or {})
    in_names = _port_names(diagram.get_input_port, diagram.num_input_ports())
    unknown = sorted(set(inputs) - set(in_names))
    if unknown:
        raise ValueError(f"simulate: diagram {diagram.get_name()!r} has no input port {unknown[0]!r}; "
                         f"inputs: {', '.join(in_names) or 'none'}")
    sources: dict[str, OutputPort] = {}
    fixed_inputs: dict[str, Any] = {}   # values of the inputs exported from the wrapper
    # a fixed input is a fixed value in the wrapper's context (no source system to notify at every
    # step) unless a log or a monitor reads it: then a ConstantVectorSource gives it an output port
    read_ports = {p if isinstance(p, str) else p.get_name()
                  for p in (log.values() if isinstance(log, Mapping) else (log or ())) if isinstance(p, (str, InputPort))}
    read_ports |= {m.port_name for m in monitors if isinstance(m, Monitor)}
    for i, name in enumerate(in_names):
        port = diagram.get_input_port(i)
        if port.get_data_type() != PortDataType.kVectorValued:
            if name in inputs:
                raise ValueError(f"simulate: input port {name!r} is abstract-valued and cannot take a schedule")
            _export(b, sub.inputs[i], name)
            if port.HasValue(user_ctx):
                fixed_inputs[name] = port.EvalAbstract(user_ctx).Clone()
            continue
        if name in inputs:
            try:
                schedule = as_schedule(inputs[name])
                src = InputSchedule(schedule, port.size(), start)   # checks the size
            except ValueError as exc:
                raise ValueError(f"simulate: input {name!r}: {exc}") from None
            value = schedule.constant()
            if value is not None:   # constant in time: Drake's C++ source, no Python callback per step
                src = ConstantVectorSource(np.broadcast_to(np.asarray(value, float), (port.size(),)).copy())
            src = b.AddNamedSystem(f"input_{name}", src)
        elif port.HasValue(user_ctx) and name not in read_ports:
            _export(b, sub.inputs[i], name)
            fixed_inputs[name] = np.asarray(port.Eval(user_ctx), float)
            continue
        elif port.HasValue(user_ctx):
            src = b.AddNamedSystem(f"fixed_{name}", ConstantVectorSource(np.asarray(port.Eval(user_ctx), float)))
        else:
            raise ValueError(f"simulate: input port {name!r} of {diagram.get_name()!r} is neither fixed in the "
                             "context nor given in inputs=")
        for dst in sub.inputs[i]:
            b.Connect(src.get_output_port(0), dst)
        sources[name] = src.get_output_port(0)

    def resolve(label: str, port) -> OutputPort:
        if isinstance(port, str):
            if diagram.HasOutputPort(port):
                return sub.GetOutputPort(port)
            if port in sources:
                return sources[port]
            outs = _port_names(diagram.get_output_port, diagram.num_output_ports())
            raise ValueError(f"simulate: diagram {diagram.get_name()!r} has no port {port!r} to log ({label!r}); "
                             f"outputs: {', '.join(outs)}; inputs: {', '.join(in_names) or 'none'}")
        if not isinstance(port, (OutputPort, InputPort)):
            raise ValueError(f"simulate: log entry {label!r} must be a port name or a port, got {type(port).__name__}")
        path = _path(diagram, port.get_system())
        if path is None:
            raise ValueError(f"simulate: port {port.get_name()!r} ({label!r}) is not in diagram {diagram.get_name()!r}")
        if not path:
            return sub.outputs[port.get_index()] if isinstance(port, OutputPort) else sources[port.get_name()]
        # a subsystem's port: only exported signals can be logged (Drake connects sinks to the top level);
        # closed loops export the plant's ports under their own names (motor_torque: the torque entering it)
        if diagram.HasOutputPort(port.get_name()):
            return sub.GetOutputPort(port.get_name())
        raise ValueError(f"simulate: port {port.get_name()!r} of subsystem {'/'.join(path)!r} ({label!r}) is not "
                         f"exported by {diagram.get_name()!r}; export it (DiagramBuilder.ExportOutput) to log it")

    if log is None:
        log = ("state",) if diagram.HasOutputPort("state") else ()
    items = list(log.items()) if isinstance(log, Mapping) else [(n, n) for n in log]
    sink_of: dict[int, Any] = {}  # id(output port) -> sink
    period_log = 0.0 if log_period is None else float(log_period)

    def sink(port: OutputPort):
        key = (id(port.get_system()), port.get_index())
        if key not in sink_of:
            sink_of[key] = LogVectorOutput(port, b, period_log)
        return sink_of[key]

    logged = [(label, sink(resolve(label, port))) for label, port in items]
    watched = []
    for m in monitors:
        if not isinstance(m, Monitor):
            raise ValueError(f"simulate: monitors must be Monitor objects (see rig_monitors), got {type(m).__name__}")
        owner = diagram if m.system is None else m.system
        target = None
        if owner is not diagram and diagram.HasOutputPort(m.port_name):
            target = diagram.GetOutputPort(m.port_name)   # exported under its own name (closed loops)
        elif owner.HasOutputPort(m.port_name):
            target = owner.GetOutputPort(m.port_name)
        elif owner.HasInputPort(m.port_name):
            target = owner.GetInputPort(m.port_name)
        if target is None:
            raise ValueError(f"simulate: monitor {m.kind!r} watches port {m.port_name!r}, which "
                             f"{owner.get_name()!r} does not have")
        watched.append((m, sink(resolve(f"monitor {m.kind}", target))))
    wrapper = b.Build()
    wrapper.set_name(f"simulate({diagram.get_name()})")

    root = wrapper.CreateDefaultContext()
    sub.copy_states_from(user_ctx, root)
    for name, value in fixed_inputs.items():
        wrapper.GetInputPort(name).FixValue(root, value)
    root.SetTime(start)

    # -- fixed-step stability of the plants' modes at the initial state --------
    if substeps is not None and (mode != "fixed_step" or sampled):
        raise ValueError(f"simulate: substeps = {substeps} needs a fixed-step run of a continuous plant (the run is "
                         + (f"{mode})" if mode != "fixed_step" else f"a sampled plant's, {sampled[0].get_name()!r})"))
    n_sub, worst = 1, None
    modes = _plant_modes(sub, root) if integrator in _TAYLOR_ORDER and mode == "fixed_step" else []
    for leaf_name, lam in modes:     # the plant needing the most substeps (0: none suffices), then the largest |R|
        k, mode_k, growth = fixed_step_substeps(lam, h, integrator)
        if worst is None or ((k or math.inf), growth) > ((worst[1] or math.inf), worst[3]):
            worst = (leaf_name, k, mode_k, growth)
    if worst is not None and worst[1] != 1:
        leaf_name, k, lam, growth = worst
        what = (f"simulate: {leaf_name!r} has the mode {_mode_text(lam)} with |R(h lambda)| = {growth:.5g} for "
                f"{integrator} at the step h = {h:.6g} s (outside its stability region: the fixed-step run would grow a "
                f"numerical oscillation)")
        if k == 0:
            raise ValueError(f"{what}; no substep count up to {_MAX_SUBSTEPS} brings it inside: use "
                             f"mode='error_controlled'")
        if substeps is None:
            warnings.warn(f"{what}; integrating at h/{k} = {h / k:.6g} s (substeps={k}; substeps=1 refuses)",
                          stacklevel=2)
            n_sub = k
        elif substeps < k:
            raise ValueError(f"{what}; substeps = {substeps} is too few: {k} put every mode inside "
                             f"(margin {FIXED_STEP_STABILITY_MARGIN:g})")
    if substeps is not None:
        n_sub = int(substeps)
    h_outer, h = h, h / n_sub

    sim = Simulator(wrapper, root)
    try:
        ResetIntegratorFromFlags(sim, integrator, h)
    except RuntimeError as exc:
        raise ValueError(f"simulate: integrator {integrator!r}: {exc}") from None
    integ = sim.get_mutable_integrator()
    if mode == "fixed_step":
        integ.set_fixed_step_mode(True)
    else:
        integ.set_target_accuracy(float(accuracy))

    # chunk boundaries: whole numbers of steps (fixed step) so chunking does not change the run
    n_chunks = max(1, min(_CHUNKS, int(duration / h)))
    if mode == "fixed_step":
        steps = max(1, int(round(duration / h / n_chunks)))
        if period is None:  # the integrator's times are repeated sums t + h: chunk at the same doubles
            bounds, tb = [], start
            for k in range(1, int(duration / h + 1e-9) + 1):
                tb = tb + h
                if k % steps == 0:
                    bounds.append(tb)
        else:               # event times are multiples of the period
            bounds = [start + k * steps * h for k in range(1, int(duration / (steps * h) + 1e-9) + 1)]
    else:
        bounds = list(start + duration * np.arange(1, n_chunks + 1) / n_chunks)
    bounds = [t for t in bounds if t < t_final - 1e-12 * max(1.0, abs(t_final))] + [float(t_final)]

    # the plant states watched for divergence: the continuous state, then each sampled plant's discrete state
    plants = [copy for leaf, copy in sub.leaves if leaf in sampled]     # the sampled plants' copies
    watched_states = [(lambda: root.get_continuous_state_vector().CopyToVector(), diagram.num_continuous_states(),
                       "state")]
    for p in plants:
        p_ctx = p.GetMyContextFromRoot(root)
        watched_states.append((lambda p=p, c=p_ctx: _sampled_plant_state(p, c),
                               p_ctx.get_discrete_state(0).size(), f"{p.get_name()} state"))

    def check_state(t_now: float):
        for get, size, what in watched_states:
            x = get()
            bad = ~np.isfinite(x) | (np.abs(np.nan_to_num(x, nan=np.inf)) > divergence_bound)
            if x.size and bad.any():
                i = int(np.argmax(bad))
                label = f"{what}[{i}]" + (f" ({state_names[i]})" if i < len(state_names) == size else "")
                raise SimulationDivergedError(
                    f"simulation of {diagram.get_name()!r} diverged at t = {t_now:.6g} s: {label} = {x[i]:.6g} "
                    f"(bound {divergence_bound:g}; checked every {duration / len(bounds):.3g} s)", t=t_now)

    def read(s):
        """Logged ``(t, values)``; samples closer than 1e-9 step to the next (a chunk boundary met
        within round-off of a step) are dropped in favour of the later one."""
        lg = s.FindLog(root)
        t, v = np.array(lg.sample_times()), np.array(lg.data().T)
        if len(t) > 1:
            keep = np.append(np.diff(t) > 1e-9 * h, True)
            t, v = t[keep], v[keep]
        return t, v

    def check_events():
        for m, s in watched:
            if not m.raise_on_event:
                continue
            evs = m.events(*read(s))
            if evs:
                e = evs[0]
                raise SimulationEventError(f"{e.kind} on {e.channel} at t = {e.t_start:.6g} s (value {e.extreme:.6g})",
                                           kind=e.kind, t=e.t_start)

    outside, excursions, checked = {}, [], []   # leaf -> [t first, t last, |R| max, mode]; closed ones; check times

    def check_modes(t_now: float):
        """The plants' modes at the current state against the region at the step taken (the end check's rule)."""
        now = {}
        for leaf_name, lam in _plant_modes(sub, root):
            excess = _excess(integrator, h * lam)
            i = int(np.argmax(excess))
            if excess[i] > 1e-9:
                now[leaf_name] = (float(stability_function(integrator, h * lam[i])), complex(lam[i]))
        for leaf_name in [nm for nm in outside if nm not in now]:
            excursions.append((leaf_name, *outside.pop(leaf_name)))
        for leaf_name, (growth, lam) in now.items():
            e = outside.setdefault(leaf_name, [t_now, t_now, growth, lam])
            e[1] = t_now
            if growth > e[2]:
                e[2:] = [growth, lam]
        checked.append(t_now)

    # checks during the run at the first chunk boundary at least FIXED_STEP_CHECK_INTERVAL simulated seconds after the
    # last check: the instants depend on the run only, never on the machine's speed
    wall, last_check = time.perf_counter(), start
    try:
        sim.Initialize()
        for tb in bounds:
            sim.AdvanceTo(tb)
            check_state(tb)
            check_events()
            if modes and tb < bounds[-1] and tb - last_check >= FIXED_STEP_CHECK_INTERVAL - 1e-9 * h:
                check_modes(tb)
                last_check = tb
            if progress is not None:
                progress(tb - start, duration)
    except (SimulationDivergedError, SimulationEventError):
        raise
    except InfeasibleForceError as exc:   # raised by a law inside the diagram: when
        exc.t = float(root.get_time())
        raise
    except (RuntimeError, SystemExit) as exc:
        t_now = root.get_time()
        check_state(t_now)
        raise SimulationError(f"simulation of {diagram.get_name()!r} failed at t = {t_now:.6g} s: {exc}") from None
    wall = time.perf_counter() - wall

    # -- collect -----------------------------------------------------------
    sub.copy_states_to(user_ctx, root)
    sampled_state = [_sampled_plant_state(p, p.GetMyContextFromRoot(root)) for p in plants]
    t = None
    signals, units, labels = {}, {}, {}
    for label, s in logged:
        ts, v = read(s)
        t = ts if t is None else t
        signals[label] = v
        port_name = label if isinstance(label, str) else str(label)
        if port_name == "state" and len(state_names) == v.shape[1]:
            units[label] = [unit(n) for n in state_names]
            labels[label] = list(state_names)
        else:
            units[label] = unit(port_name)
            labels[label] = [f"{port_name}[{j}]" for j in range(v.shape[1])] if v.shape[1] > 1 else [port_name]
    if t is None:
        t = read(watched[0][1])[0] if watched else np.array([start, float(t_final)])
    events = []
    for m, s in watched:
        events.extend(m.events(*read(s)))
    if modes:                                   # the same check at the end state closes every excursion
        check_modes(float(t_final))
        excursions.extend((nm, *e) for nm, e in outside.items())
    for leaf_name, t0, t1, growth, lam in excursions:
        events.append(Event("integrator_instability", leaf_name, t0, t1, growth))
        warnings.warn(f"simulate: from t = {t0:.6g} to {t1:.6g} s (checked at {len(checked)} instants) {leaf_name!r} "
                      f"had the mode {_mode_text(lam)} outside {integrator}'s stability region at h = {h:.6g} s "
                      f"(|R| up to {growth:.5g}): the run is not trustworthy from there; give more substeps or "
                      f"mode='error_controlled'", stacklevel=2)
    events.sort(key=lambda e: (e.t_start, e.kind, e.channel))
    limits = {}   # thresholds of monitors watching a logged signal, drawn by SimulationResult.plot
    for m, s in watched:
        for label, ls in logged:
            if (ls is s if m.limits_on is None else label == m.limits_on) and m.limits():
                limits.setdefault(label, []).extend([(str(d), float(v)) for d, v in m.limits()])
    info = dict(mode=mode, integrator=integrator, step=h if mode == "fixed_step" else None,
                substeps=n_sub if mode == "fixed_step" else None,
                fastest_mode=None if worst is None else dict(system=worst[0], mode=worst[2], growth=worst[3],
                                                             step=h_outer),
                stability_checks=checked if modes else None,
                max_step=h if mode == "error_controlled" else None,
                accuracy=float(accuracy) if mode == "error_controlled" else None,
                control_period=period, t_start=start, t_final=float(t_final), wall_time=wall,
                realtime_factor=duration / wall if wall > 0 else math.inf,
                steps=int(integ.get_num_steps_taken() if diagram.num_continuous_states() else sim.get_num_discrete_updates()),
                sampled_plants=[p.get_name() for p in sampled], system=diagram.get_name())
    return SimulationResult(np.array(t), signals, events, user_ctx, units, labels, info, limits,
                            np.concatenate(sampled_state) if sampled_state else None)
