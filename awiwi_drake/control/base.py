"""Controller API: named-port controllers and the closed-loop builder.

Conventions (binding for every controller in :mod:`awiwi_drake.control`)
-----------------------------------------------------------------------
* A controller is a Drake system (a scalar-convertible ``TemplateSystem`` or a
  C++ primitive / diagram of primitives) whose

  - input ports named ``<signal>_reference`` carry the reference of the rig
    output ``<signal>`` (e.g. ``tendon_force_reference`` tracks the rig output
    ``tendon_force``; ``joint_angle_reference`` tracks ``joint_angle``), or of a
    quantity the controller itself outputs under the name ``<signal>`` when the
    rig cannot measure it (``effective_stiffness_reference`` of the ch. 8
    stiffness correction: the controller reports ``effective_stiffness``);
  - other input ports are *measurements* and carry exactly the name of a rig
    output port (``state``, ``tendon_force``, ``motor_velocity``, ...);
  - one output port ``motor_torque`` [Nm] is the command (size = rig input).

* :func:`closed_loop` wires a rig and a controller by these names (sampling, delay, saturation, sensor models,
  state estimator: its parameters) and returns a :class:`ClosedLoop` handle.
* Fingers and the hand have no joint sensors (section 5.2.3): their controllers' ``joint_angle`` /
  ``joint_velocity`` come from the rig's tendon-length estimator ((5.15), Algorithm 1 for the thumb base) unless
  ``sensors="ideal"``; a controller reading the full ``state`` (the true joint angles) is refused there.

Most controllers of the thesis are static laws ``u = law(inputs)``; they are
built with :class:`StaticLawController_`, which evaluates a pure, scalar-generic
law object (float and AutoDiffXd) so that every controller converts with
``ToAutoDiffXd()`` and can be linearised together with the rig.
"""

from __future__ import annotations

import abc
import math
import sys
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np
from pydrake.systems.framework import Context, Diagram, DiagramBuilder, LeafSystem_, System
from pydrake.systems.primitives import DiscreteTimeDelay, MatrixGain, Multiplexer, Saturation, ZeroOrderHold
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake.analysis.simulate import add_flat

__all__ = [
    "COMMAND_PORT",
    "REFERENCE_SUFFIX",
    "check_gain",
    "check_gains",
    "check_rate",
    "StaticLaw",
    "StaticLawController_",
    "StaticLawController",
    "ClosedLoop",
    "closed_loop",
    "reference_ports",
    "measurement_ports",
]

COMMAND_PORT = "motor_torque"
REFERENCE_SUFFIX = "_reference"
_ROUND_TRIP_TOLERANCE = 0.01  # delay must be a whole number of periods within 1 % of a period


# ----------------------------------------------------------------------------
# gain validation
def check_gain(name: str, value: Any, *, allow_zero: bool = False, owner: str = "controller") -> float:
    """Validate one scalar gain; return it as float.

    Raises
    ------
    ValueError
        Naming ``owner.name`` when the gain is not a finite real number, is
        non-positive (``allow_zero=False``) or negative.
    """
    label = f"{owner} gain {name!r}"
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{label} = {value!r} is not a number") from None
    if not math.isfinite(v):
        raise ValueError(f"{label} = {v!r} is not finite")
    if v < 0.0 or (v == 0.0 and not allow_zero):
        need = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{label} = {v!r} must be {need}")
    return v


def check_rate(owner: str, rate_hz: Any) -> float:
    """Validate a sampling rate ``rate_hz`` [Hz] (a finite real number > 0); return it as float.

    Raises
    ------
    ValueError
        One line naming ``owner`` and ``rate_hz``.
    """
    if isinstance(rate_hz, (bool, np.bool_)) or not isinstance(rate_hz, (int, float, np.integer, np.floating)) \
            or not 0.0 < float(rate_hz) < math.inf:
        raise ValueError(f"{owner}: rate_hz = {rate_hz!r} must be a finite number > 0 [Hz]")
    return float(rate_hz)


def check_gains(name: str, values: Any, *, shape: tuple[int, ...] | None = None,
                owner: str = "controller", positive: bool = False) -> np.ndarray:
    """Validate a gain vector/matrix: finite (and positive when asked); return a float array."""
    try:
        arr = np.array(values, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{owner} gain {name!r} = {values!r} is not numeric") from None
    if shape is not None and arr.shape != tuple(shape):
        raise ValueError(f"{owner} gain {name!r} has shape {arr.shape}, expected {tuple(shape)}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{owner} gain {name!r} contains non-finite entries: {arr!r}")
    if positive and not np.all(arr > 0.0):
        raise ValueError(f"{owner} gain {name!r} must be > 0 element-wise, got {arr!r}")
    return arr


# ----------------------------------------------------------------------------
# static-law controllers
class StaticLaw(abc.ABC):
    """Base class of a pure controller law ``u = law(inputs)``.

    Subclasses set ``inputs`` (ordered mapping port name -> size),
    ``output_size`` and implement :meth:`__call__` taking a dict of numpy
    arrays (float or object arrays of AutoDiffXd) and returning the command
    array.  Laws must be written with numpy ufuncs and
    :mod:`awiwi_drake._math` so that float and AutoDiffXd pass through.
    """

    name: str = "controller"
    inputs: Mapping[str, int] = {}
    output_size: int = 1

    @abc.abstractmethod
    def __call__(self, u: Mapping[str, np.ndarray]) -> np.ndarray:
        """The command for the given named inputs."""


@TemplateSystem.define("StaticLawController_", scope=sys.modules[__name__])
def StaticLawController_(T):
    """A feedthrough controller evaluating a :class:`StaticLaw` (float, AutoDiffXd)."""

    class Impl(LeafSystem_[T]):
        def _construct(self, law: StaticLaw, converter=None):
            LeafSystem_[T].__init__(self, converter)
            if not isinstance(law, StaticLaw):
                raise ValueError(f"StaticLawController: law must be a StaticLaw, got {type(law).__name__}")
            self.law = law
            self._ports = []
            for pname, size in law.inputs.items():
                self._ports.append((pname, self.DeclareVectorInputPort(pname, int(size))))
            tickets = {p.ticket() for _, p in self._ports}
            self.DeclareVectorOutputPort(COMMAND_PORT, int(law.output_size), self._calc,
                                         prerequisites_of_calc=tickets)
            self.set_name(law.name)

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.law, converter=converter)

        def _calc(self, context, output):
            values = {name: port.Eval(context) for name, port in self._ports}
            out = self.law(values)
            output.SetFromVector(np.asarray(out).reshape(-1))

    return Impl


StaticLawController = StaticLawController_[None]


# ----------------------------------------------------------------------------
# port helpers
def _input_names(system: System) -> list[str]:
    return [system.get_input_port(i).get_name() for i in range(system.num_input_ports())]


def _output_names(system: System) -> list[str]:
    return [system.get_output_port(i).get_name() for i in range(system.num_output_ports())]


def reference_ports(controller: System) -> list[str]:
    """Names of the controller's ``*_reference`` input ports."""
    return [n for n in _input_names(controller) if n.endswith(REFERENCE_SUFFIX)]


def measurement_ports(controller: System) -> list[str]:
    """Names of the controller's measurement input ports (all non-reference inputs)."""
    return [n for n in _input_names(controller) if not n.endswith(REFERENCE_SUFFIX)]


# ----------------------------------------------------------------------------
@dataclass
class ClosedLoop:
    """Handles of a closed loop built by :func:`closed_loop`.

    Exported diagram ports: inputs ``<signal>_reference`` (one per controller
    reference) and every rig input other than ``motor_torque`` (e.g.
    ``external_torque``, ``wrist_angle``); outputs: every rig output under its own
    name, the controller command ``motor_torque_command`` and the torque entering
    the rig ``motor_torque`` (after hold, delay and saturation), any other
    controller output ``<name>`` as ``controller_<name>``, and with an estimator,
    for each estimated quantity ``<q>`` (e.g. ``joint_angle``) ``<q>_estimate``
    and ``<q>_estimation_error`` = estimate - true value.
    """

    diagram: Diagram
    rig: Any
    controller: System
    rate_hz: float | None
    delay: float | None
    delay_steps: int
    saturation: np.ndarray | None
    references: tuple[str, ...]
    disturbances: tuple[str, ...]
    tracked_outputs: tuple[str, ...]
    estimator: Any = None
    estimated: tuple[str, ...] = ()
    sampled_rig: bool = False
    fused: Any = None
    _holds: list = field(default_factory=list, repr=False)
    _sampled: Any = field(default=None, repr=False)     # a sampled rig's RigPorts (its systems are in the loop)
    _delays: list = field(default_factory=list, repr=False)

    @property
    def num_inputs(self) -> int:
        """Size of the command ``motor_torque``."""
        return self.diagram.GetOutputPort(COMMAND_PORT).size()

    def create_context(self, op: Any = None, *, state: Sequence[float] | None = None,
                       motor_torque: Sequence[float] | float | None = None,
                       references: Mapping[str, Any] | None = None,
                       disturbances: Mapping[str, Any] | None = None) -> Context:
        """A context with the rig state set, references/disturbances fixed.

        ``op`` (an :class:`~awiwi_drake.rigs.OperatingPoint`) gives the state,
        the holding torques and the external torque at once (``state`` /
        ``motor_torque`` / ``disturbances`` override it).  ``motor_torque``
        initialises the sample-and-hold and delay buffers (so the first control
        periods apply the operating-point torque instead of zero).  Unspecified
        references/disturbances are fixed to zero.
        """
        disturbances = dict(disturbances or {})
        if op is not None:
            state = op.state if state is None else state
            motor_torque = op.motor_torque if motor_torque is None else motor_torque
            if op.external_torque is not None and "external_torque" in self.disturbances:
                disturbances.setdefault("external_torque", op.external_torque)
        ctx = self.diagram.CreateDefaultContext()
        self.initialize(ctx, state=state, motor_torque=motor_torque)
        references = dict(references or {})
        for name in self.references:
            port = self.diagram.GetInputPort(name)
            port.FixValue(ctx, _vector(references.pop(name, 0.0), port.size(), name))
        for name in self.disturbances:
            port = self.diagram.GetInputPort(name)
            port.FixValue(ctx, _vector(disturbances.pop(name, 0.0), port.size(), name))
        unknown = sorted(set(references) | set(disturbances))
        if unknown:
            raise ValueError(f"closed loop has no input port {unknown[0]!r}; inputs: "
                             f"{', '.join(self.references + self.disturbances)}")
        return ctx

    def initialize(self, context: Context, *, state=None, motor_torque=None) -> None:
        """Set the rig state and the hold/delay buffers in a (root) context.

        ``context`` may be the root context of a larger diagram holding this
        closed loop.  With an estimator, the estimate starts at the joint angles
        of ``state`` (a pose known after homing).
        """
        if state is not None:
            rig_sys = self._sampled.dynamics if self.sampled_rig else self.diagram.GetSubsystemByName("rig")
            rig_ctx = rig_sys.GetMyMutableContextFromRoot(context)
            x = np.asarray(state, dtype=float).reshape(-1)
            n = rig_ctx.get_discrete_state(0).size() if self.sampled_rig else rig_ctx.num_continuous_states()
            if x.size != n:
                raise ValueError(f"closed_loop: state has {x.size} entries, the rig has {n} states")
            if not np.all(np.isfinite(x)):
                bad = int(np.flatnonzero(~np.isfinite(x))[0])
                raise ValueError(f"closed_loop: state[{bad}] ({self.rig.state_names[bad]}) = {x[bad]} must be finite")
            if self.sampled_rig:     # the sampled dynamics' discrete state: x in the rig's integration coordinates
                rig_ctx.SetDiscreteState(0, self.rig.sampled_state(x))
            else:
                rig_ctx.SetContinuousState(x)
            self.initialize_controller(context, self.rig.joint_angles_of(x) if self.estimator is not None else None,
                                       rig_state=x)
        if motor_torque is not None:
            u = _vector(motor_torque, self.num_inputs, "motor_torque")
            for zoh in self._holds:       # with a sampled rig, its hold of its input too
                zoh.SetVectorState(zoh.GetMyMutableContextFromRoot(context), u)
            for d in self._delays:
                dctx = d.GetMyMutableContextFromRoot(context)
                nbuf = dctx.get_discrete_state_vector().size() // u.size
                dctx.SetDiscreteState(np.tile(u, nbuf))


    def initialize_controller(self, context: Context, joint_angles=None, *, rig_state=None) -> None:
        """Start the controller's states (e.g. the force distribution at its design forces) and, given
        ``joint_angles`` (a pose known after homing), the estimator's, in a (root) ``context``."""
        if self.fused is not None:
            n = self.rig.num_joints
            self.fused.initialize_state(self.fused.GetMyMutableContextFromRoot(context), joint_angles,
                                        None if rig_state is None else np.asarray(rig_state, float)[n:2 * n])
            return
        init = getattr(self.controller, "initialize_state", None)
        if init is not None:   # controllers with internal state (e.g. the force distribution)
            init(self.diagram.GetSubsystemByName("controller").GetMyMutableContextFromRoot(context), rig_state)
        if joint_angles is not None and self.estimator is not None and hasattr(self.estimator, "initialize"):
            est_sys = self.diagram.GetSubsystemByName("estimator")
            self.estimator.initialize(est_sys.GetMyMutableContextFromRoot(context), joint_angles)


def _vector(value, size: int, name: str) -> np.ndarray:
    v = np.atleast_1d(np.asarray(value, dtype=float)).reshape(-1)
    if v.size == 1 and size > 1:
        v = np.full(size, float(v[0]))
    if v.size != size:
        raise ValueError(f"{name}: expected {size} values, got {v.size}")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name}: values must be finite, got {v}")
    return v


def closed_loop(rig: Any, controller: System, *, rate_hz: float | None = 3000.0,
                delay: float | None = None, saturation: float | Sequence[float] | None = None,
                sensors: Mapping[str, System] | str | None = None, estimator: Any = "auto",
                sources: Mapping[str, System] | None = None, name: str | None = None,
                sampled_rig: bool = True, fused: bool = True) -> ClosedLoop:
    """Close the loop between a rig and a controller by port names.

    Parameters
    ----------
    rig : Rig
        Any object with a ``diagram`` exporting the input ``motor_torque`` and
        the measurement outputs (the :class:`awiwi_drake.rigs.Rig` contract):
        the tendon rig, the flexible joint, the joint rig, a finger or the hand.
    controller : System
        Controller following the naming conventions of this module.
    rate_hz : float or None
        Control rate [Hz]: the command is sampled and held (zero-order hold)
        every ``1/rate_hz`` s (3 kHz in the Awiwi hand).  ``None``: continuous
        controller (needed for :func:`awiwi_drake.analysis.linearize`).
    delay : float or None
        Round-trip delay [s] (333e-6 s in the hand), realised by a
        ``DiscreteTimeDelay`` of ``round(delay * rate_hz)`` periods; requires
        ``rate_hz`` and must be a whole number of periods within 1 %.
    saturation : float or sequence or None
        Symmetric torque limit [Nm] applied to the command (Drake
        ``Saturation``).  ``None``: the rig's own limit (if any) applies.
    sensors : mapping, "ideal" or None
        ``{rig_output_name: system}``: a sensor model with one input and one
        output inserted between that rig output and the controller input.
        ``"ideal"``: every measurement is the rig's true output (e.g. the true joint state of a finger for an
        "ideal sensor" comparison); in a sampled loop (``rate_hz``) the rig's own estimator (``estimator="auto"``)
        still runs beside it on the same samples, its output not fed back, so that the loop reports
        ``<q>_estimate`` and ``<q>_estimation_error`` (what the estimator would have given the controller) as
        with estimated sensors; ``estimator=None`` leaves it out.
    estimator : "auto", None or object
        ``"auto"`` (default): the rig's own state estimator when it has one
        (fingers and the hand: ``rig.link_estimator(period)``, joint angles
        from tendon lengths, at the control rate but never faster than the
        sensors' 3 kHz); with ``sensors="ideal"`` only beside the loop (above), and not in a continuous loop.  ``None``: no
        estimator.  Or an object with ``system`` (a Drake System whose inputs
        are named after rig outputs and whose outputs replace the rig outputs of
        the same name as controller measurements) and optionally
        ``initialize(context, joint_angles)``.
    sources : mapping, optional
        ``{input_name: system}``: a signal source (one output port, e.g. a
        ``TrajectorySource`` or ``Sine``) wired to a reference input or a rig
        input (``external_torque``, ``wrist_angle``) instead of exporting it.
    name : str, optional
        Diagram name (default ``"<rig>_<controller>"``).
    sampled_rig : bool
        For a sampled loop on a rig that offers ``rig.sampled_diagram`` (the single-joint rigs and the tendon rig)
        whose controller and sensors have no continuous state and update, if at all, at the control period (default
        True): the rig enters the loop as Drake's ``DiscreteTimeApproximation`` at the control period
        (:func:`~awiwi_drake.components.rig_system.sampled_dynamics`: fixed-step RK3, one step per period, its inputs
        held), so the ``Simulator`` does one update per period.  It reads the command at the sample instant, so it
        replaces the command's hold (a round-trip delay keeps its length); the trajectory equals the continuous rig's
        under ``simulate``'s default fixed-step RK3 to round-off (tests/test_rig_system.py).  Its discrete state is in
        its integration coordinates (``Rig.sampled_state``; :meth:`ClosedLoop.create_context` maps a physical state
        in).  Its systems, and the leaves of a plain controller ``Diagram`` that support scalar conversion, are added
        to the loop directly (one leaf is named ``"controller"``, several ``"controller.<path>"``).  False: the
        continuous rig behind a zero-order hold.
    fused : bool
        For a finger or the hand whose joint state comes from the rig's own estimator (``estimator="auto"``, no
        ``sensors``) and a controller that offers it (the chain without the friction observer, or a
        :class:`StaticLawController_` reading the estimated joint state, e.g. the 15.5 backstepping) (default True):
        estimator, velocity filter and controller are ONE discrete system
        (:class:`~awiwi_drake.control.fused.FusedChain_`) with the same ports, equal to the composed loop
        (tests/test_fused_chain.py).  False: the ``"estimator"`` and ``"controller"`` subsystems.

    Returns
    -------
    ClosedLoop
    """
    rig_diagram = getattr(rig, "diagram", None)
    if not isinstance(rig_diagram, System):
        raise ValueError(f"closed_loop: rig must have a Drake system in .diagram, got {type(rig).__name__}")
    if not isinstance(controller, System):
        raise ValueError(f"closed_loop: controller must be a Drake System, got {type(controller).__name__}")
    rig_name = getattr(rig, "name", "?")
    rig_in, rig_out = _input_names(rig_diagram), _output_names(rig_diagram)
    ctrl_out = _output_names(controller)
    if COMMAND_PORT not in rig_in:
        raise ValueError(f"closed_loop: rig {rig_name!r} has no input port {COMMAND_PORT!r}")
    if COMMAND_PORT not in ctrl_out:
        raise ValueError(f"closed_loop: controller {controller.get_name()!r} has no output port "
                         f"{COMMAND_PORT!r} (outputs: {', '.join(ctrl_out) or 'none'})")
    n_u = rig_diagram.GetInputPort(COMMAND_PORT).size()
    if controller.GetOutputPort(COMMAND_PORT).size() != n_u:
        raise ValueError(f"closed_loop: controller port {COMMAND_PORT!r} has size "
                         f"{controller.GetOutputPort(COMMAND_PORT).size()}, rig input has size {n_u}")
    refs = reference_ports(controller)
    tracked = []
    for r in refs:
        sig = r[: -len(REFERENCE_SUFFIX)]
        if sig in rig_out:
            tracked.append(sig)
        elif sig not in ctrl_out:
            raise ValueError(f"closed_loop: controller reference port {r!r} refers to {sig!r}, which neither the rig "
                             f"{rig_name!r} outputs (outputs: {', '.join(rig_out)}) nor the controller reports")

    def check_reads_rig(what, system, names):
        """Each input ``names`` of ``system`` is a rig output of the same size."""
        for m in names:
            if m not in rig_out:
                raise ValueError(f"closed_loop: {what} {m!r} is not an output of rig {rig_name!r} "
                                 f"(outputs: {', '.join(rig_out)})")
            if system.GetInputPort(m).size() != rig_diagram.GetOutputPort(m).size():
                raise ValueError(f"closed_loop: {what} {m!r} has size {system.GetInputPort(m).size()} but "
                                 f"{rig_diagram.GetOutputPort(m).size()} on rig {rig_name!r}")
    check_reads_rig("controller measurement port", controller, measurement_ports(controller))
    ideal = isinstance(sensors, str)
    if ideal and sensors != "ideal":
        raise ValueError(f"closed_loop: sensors = {sensors!r}; give 'ideal', a mapping {{rig output: system}} "
                         f"or None")
    if rate_hz is not None:
        rate_hz = check_rate("closed_loop (None: continuous)", rate_hz)
    est = _resolve_estimator(rig, estimator, ideal, rate_hz, measurement_ports(controller))
    est_sys = None if est is None else getattr(est, "system", est)
    est_out = [] if est_sys is None else _output_names(est_sys)
    # with ideal sensors the rig's estimator runs beside the loop (its error reported, its output not fed back)
    estimated = () if ideal else tuple(m for m in measurement_ports(controller) if m in est_out)
    if est_sys is not None:
        if not isinstance(est_sys, System):
            raise ValueError(f"closed_loop: estimator must be a Drake System or have one in .system, got "
                             f"{type(est_sys).__name__}")
        check_reads_rig("estimator input", est_sys, _input_names(est_sys))
    if not ideal and not _joint_sensors(rig) and "state" in measurement_ports(controller):
        raise ValueError(f"closed_loop: controller {controller.get_name()!r} reads the rig's full 'state' "
                         f"(true joint angles), but rig {rig_name!r} has no joint sensors: its joint state "
                         f"comes from the tendon-length estimator (joint_angle, joint_velocity); use "
                         f"sensors='ideal' for a true-state comparison")
    sensors = {} if ideal else dict(sensors or {})
    for s in sensors:
        if s not in rig_out:
            raise ValueError(f"closed_loop: sensor given for {s!r}, which is not a rig output")
    steps = 0
    if delay is not None:
        delay = float(delay)
        if not math.isfinite(delay) or delay < 0.0:
            raise ValueError(f"closed_loop: delay = {delay!r} must be >= 0 s")
        if delay > 0.0:
            if rate_hz is None:
                raise ValueError("closed_loop: delay needs a sampled controller (give rate_hz)")
            steps = int(round(delay * rate_hz))
            if steps < 1 or abs(steps - delay * rate_hz) > _ROUND_TRIP_TOLERANCE:
                raise ValueError(f"closed_loop: delay = {delay!r} s is not a whole number of control "
                                 f"periods (1/{rate_hz:g} s) within 1 %")
    sat = None
    if saturation is not None:
        sat = _vector(saturation, n_u, "saturation")
        if np.any(sat <= 0.0):
            raise ValueError(f"closed_loop: saturation = {sat} must be > 0 Nm")

    spec = None
    if fused and est is not None and not ideal and not sensors and hasattr(est, "fused_spec"):
        if hasattr(controller, "fused_spec"):
            spec = controller.fused_spec(est)
        elif isinstance(controller, StaticLawController) and estimated:
            spec = dict(est.fused_spec(), law=controller.law, name=controller.get_name())
    if spec is not None:
        from awiwi_drake.control.fused import ESTIMATE_OUTPUTS, FusedChain
        fused_sys = FusedChain(spec)
        est_sys = None
    # the rig as a discrete-time system at the control period where that is the same loop: every reader
    # of the rig's outputs samples them at the control instants (no continuous state outside the rig)
    sample_rig = bool(sampled_rig and rate_hz is not None and getattr(rig, "sampled_diagram", None) is not None
                      and est_sys is None and all(_updates_with_the_rig(s, 1.0 / rate_hz)
                                                  for s in (controller, *sensors.values())))
    builder = DiagramBuilder()
    # a sampled rig's systems and a plain controller diagram's leaves go into the loop's builder directly (a
    # sub-diagram costs the simulator ~0.3-1 us per period, README "How the plants are built, and speed")
    plant = (rig.add_sampled(builder, 1.0 / rate_hz, hold_applied_torque=True) if sample_rig
             else builder.AddNamedSystem("rig", rig_diagram))
    if sample_rig and spec is None and _flattenable(controller):
        ctrl = add_flat(builder, controller, "controller")
        if len(ctrl.leaves) == 1:
            ctrl.leaves[0][1].set_name("controller")
    else:
        ctrl = builder.AddNamedSystem("controller", controller if spec is None else fused_sys)
    handles = ClosedLoop(diagram=None, rig=rig, controller=controller, rate_hz=rate_hz,
                         delay=(steps / rate_hz if steps else None), delay_steps=steps, saturation=sat,
                         references=tuple(refs), disturbances=(), tracked_outputs=tuple(tracked),
                         estimator=est, estimated=estimated, sampled_rig=sample_rig,
                         fused=None if spec is None else fused_sys)
    if sample_rig:
        handles._sampled = plant
        handles._holds.append(plant.hold)
    estimate_ports = {}
    if spec is not None:      # the estimates are the fused system's outputs; its inputs are rig outputs
        estimate_ports = {q: ctrl.GetOutputPort(ESTIMATE_OUTPUTS[q]) for q in estimated}
        for q, port in estimate_ports.items():
            builder.ExportOutput(port, f"{q}_estimate")
    if est_sys is not None:
        e = builder.AddNamedSystem("estimator", est_sys)
        for m in _input_names(est_sys):
            builder.Connect(plant.GetOutputPort(m), e.GetInputPort(m))
        for q in est_out:
            estimate_ports[q] = e.GetOutputPort(q)
            builder.ExportOutput(e.GetOutputPort(q), f"{q}_estimate")
    for q, port in estimate_ports.items():
        if q in rig_out:  # estimation error = estimate - truth
            nq = port.size()
            mux = builder.AddNamedSystem(f"{q}_error_inputs", Multiplexer([nq, nq]))
            diff = builder.AddNamedSystem(f"{q}_estimation_error",
                                          MatrixGain(np.hstack([np.eye(nq), -np.eye(nq)])))
            builder.Connect(port, mux.get_input_port(0))
            builder.Connect(plant.GetOutputPort(q), mux.get_input_port(1))
            builder.Connect(mux.get_output_port(), diff.get_input_port())
            builder.ExportOutput(diff.get_output_port(), f"{q}_estimation_error")
    # measurements (from the estimator, optionally through sensor models); the fused system reads rig outputs
    for m in (measurement_ports(controller) if spec is None else measurement_ports(fused_sys)):
        if spec is not None:
            builder.Connect(plant.GetOutputPort(m), ctrl.GetInputPort(m))
            continue
        src = estimate_ports[m] if m in estimated else plant.GetOutputPort(m)
        if m in sensors:
            sensor = builder.AddNamedSystem(f"sensor_{m}", sensors[m])
            if sensor.num_input_ports() != 1 or sensor.num_output_ports() != 1:
                raise ValueError(f"closed_loop: sensor for {m!r} must have exactly one input and one output")
            builder.Connect(src, sensor.get_input_port(0))
            src = sensor.get_output_port(0)
        _connect(builder, src, ctrl.GetInputPort(m))
    # command path: controller -> hold -> delay -> saturation -> rig
    cmd = ctrl.GetOutputPort(COMMAND_PORT)
    builder.ExportOutput(cmd, "motor_torque_command")
    # A DiscreteTimeDelay samples its input every period and outputs it `steps` periods later, so it is
    # the sample-and-hold itself (a ZOH in front would add a period: simultaneous updates read the
    # pre-update hold value). A sampled rig samples its input itself: it reads the command at the
    # instant (steps = 0), through a hold (1) or a delay of steps - 1 periods; its own hold of its input
    # (held_motor_torque) gives the loop's motor_torque output the held command, as the continuous rig sees it.
    lag = steps - 1 if sample_rig else steps
    if rate_hz is not None and lag == 0:
        zoh = builder.AddNamedSystem("command_hold", ZeroOrderHold(1.0 / rate_hz, n_u))
        builder.Connect(cmd, zoh.get_input_port(0))
        cmd = zoh.get_output_port(0)
        handles._holds.append(zoh)
    if lag > 0:
        dly = builder.AddNamedSystem("round_trip_delay", DiscreteTimeDelay(1.0 / rate_hz, lag, n_u))
        builder.Connect(cmd, dly.get_input_port())
        cmd = dly.get_output_port()
        handles._delays.append(dly)
    if sat is not None:
        satsys = builder.AddNamedSystem("torque_saturation", Saturation(-sat, sat))
        builder.Connect(cmd, satsys.get_input_port(0))
        cmd = satsys.get_output_port(0)
    _connect(builder, cmd, plant.GetInputPort(COMMAND_PORT))
    # the torque entering the rig over the current period: a sampled rig holds its input itself
    builder.ExportOutput(plant.GetOutputPort("held_motor_torque") if sample_rig else cmd, COMMAND_PORT)
    sources = dict(sources or {})
    unknown = sorted(set(sources) - set(refs) - (set(rig_in) - {COMMAND_PORT}))
    if unknown:
        raise ValueError(f"closed_loop: source given for {unknown[0]!r}, which is neither a controller reference "
                         f"nor a rig input (inputs: {', '.join(refs + [n for n in rig_in if n != COMMAND_PORT])})")

    def _feed(name, port):
        ports = port if isinstance(port, list) else [port]    # a flat sampled rig's input may feed several systems
        if name not in sources:
            builder.ExportInput(ports[0], name)
            for p in ports[1:]:
                builder.ConnectInput(name, p)
            return True
        src = builder.AddNamedSystem(f"{name}_source", sources[name])
        size = ports[0].size()
        if src.num_output_ports() != 1 or src.get_output_port(0).size() != size:
            raise ValueError(f"closed_loop: the source for {name!r} must have one output port of size {size}")
        _connect(builder, src.get_output_port(0), port)
        return False

    refs = [r for r in refs if _feed(r, ctrl.GetInputPort(r))]
    handles.references = tuple(refs)
    dist = [n for n in rig_in if n != COMMAND_PORT and _feed(n, plant.GetInputPort(n))]
    for n in rig_out:
        if n != COMMAND_PORT:
            builder.ExportOutput(plant.GetOutputPort(n), n)
    for n in ctrl_out:  # e.g. the SDRE gain, exported as controller_<name>
        if n != COMMAND_PORT and not (spec is not None and n in ESTIMATE_OUTPUTS.values()):
            builder.ExportOutput(ctrl.GetOutputPort(n), f"controller_{n}")
    try:
        diagram = builder.Build()
    except RuntimeError as exc:
        if "already been built into" in str(exc):
            raise ValueError(
                f"closed_loop: rig {rig_name!r} or controller {controller.get_name()!r} is already "
                f"part of another closed loop (a Drake system belongs to one diagram): build a fresh rig and "
                f"controller for each closed_loop call (e.g. rig = tendon_rig(); ctrl = factory(rig))") from None
        if "algebraic loop" not in str(exc):
            raise
        raise ValueError(
            f"closed_loop: continuous loop (rate_hz=None) of rig {rig_name!r} and controller "
            f"{controller.get_name()!r} has an algebraic loop: the rig reports direct feedthrough from "
            f"motor_torque to its outputs; use a sampled controller (rate_hz)") from None
    diagram.set_name(name or f"{getattr(rig, 'name', 'rig')}_{controller.get_name()}")
    handles.diagram = diagram
    handles.disturbances = tuple(dist)
    return handles


def _updates_with_the_rig(system: System, period: float) -> bool:
    """Whether ``system`` can run beside a rig sampled at ``period``: no continuous state, and its discrete
    updates (if any) all at ``period`` with offset 0.  An update at another rate (the SDRE's 200 Hz gain refresh,
    ch. 14) can fall an ulp after the rig's update at the same nominal instant (Drake times each rate as a multiple of
    its own period) and would read the sampled rig's next state."""
    if system.num_continuous_states():
        return False
    attr = system.GetUniquePeriodicDiscreteUpdateAttribute()     # None: no periodic update, or several timings
    if attr is None:
        return system.num_discrete_state_groups() == 0
    return attr.period_sec() == period and attr.offset_sec() == 0.0


def _flattenable(controller: System) -> bool:
    """A plain ``Diagram`` (not a Python subclass with methods of its own, e.g. ``initialize_state``) whose leaves
    can be copied (:func:`_copyable`)."""
    if type(controller) is not Diagram or hasattr(controller, "initialize_state"):
        return False
    return _copyable(controller)


def _copyable(system: System) -> bool:
    """Whether :func:`~awiwi_drake.analysis.add_flat` can copy every leaf of ``system``: a ``TemplateSystem`` copies
    itself (its ``_construct_copy``), any other leaf needs scalar conversion (``Clone``), checked per leaf so the
    TemplateSystem leaves are not cloned through AutoDiffXd only to be copied again."""
    if isinstance(system, Diagram):
        return all(_copyable(s) for s in system.GetSystems())
    if getattr(type(system), "_construct_copy", None) is not None:
        return True
    try:
        system.Clone()
    except RuntimeError:
        return False
    return True


def _connect(builder, src, dst) -> None:
    """Connect ``src`` to the input port ``dst`` or to each of a list of them (a flat sampled rig's input)."""
    for port in (dst if isinstance(dst, list) else [dst]):
        builder.Connect(src, port)


def _joint_sensors(rig: Any) -> bool:
    """Whether ``rig`` measures its joint angles (:attr:`Rig.joint_sensors`; a rig-like object that is no
    :class:`~awiwi_drake.rigs.base.Rig` has its own outputs only)."""
    from awiwi_drake.rigs.base import Rig          # loaded with any Rig: free here
    return not isinstance(rig, Rig) or rig.joint_sensors


def _resolve_estimator(rig: Any, estimator: Any, ideal: bool, rate_hz: float | None, measured: list[str]):
    """The estimator object for :func:`closed_loop` (None: measurements straight from the rig).

    ``"auto"`` uses the rig's estimator only when the controller measures one
    of its outputs (a motor-side controller such as the joint PD needs none).
    """
    if estimator is None:
        return None
    if isinstance(estimator, str):
        if estimator != "auto":
            raise ValueError(f"closed_loop: estimator = {estimator!r}; give 'auto', None or an estimator")
        if _joint_sensors(rig) or (ideal and rate_hz is None):
            return None
        est = rig.link_estimator(None if rate_hz is None else 1.0 / rate_hz)
        used = [m for m in measured if m in _output_names(est.system)]
        if not used:
            return None
        if rate_hz is None:
            raise ValueError(f"closed_loop: rig {getattr(rig, 'name', '?')!r} has no joint sensors; "
                             f"{', '.join(used)} come from its tendon-length estimator, which runs at the "
                             f"control rate: give rate_hz, or sensors='ideal' for a continuous loop on the "
                             f"true joint state")
        return est
    if ideal:
        raise ValueError("closed_loop: sensors='ideal' and an estimator exclude each other")
    return estimator
