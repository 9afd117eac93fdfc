"""Tendon drive: N motors + N spring mechanisms + routing to n joints, as one sub-diagram.

Three backends build the same physics with the same port names:

``backend="compiled"`` (default)
    one :class:`~awiwi_drake.components.fused_drive.TendonDrive_` system: numba
    kernels generated from the law functions for float, the law functions
    themselves for AutoDiffXd/Expression; one spring law per tendon, guide
    friction and hysteresis; every output port computes only its own quantity.
``backend="python"``
    :class:`MotorBank_`, :class:`SpringBank_` and :class:`TendonRouting_` wired
    together (the modular reference; any spring law, hysteresis).
``backend="symbolic"``
    one C++ ``SymbolicVectorSystem`` whose equations are the compiled drive's
    :func:`~awiwi_drake.components.fused_drive.drive_laws` (the same law functions)
    evaluated on symbolic variables. Drake evaluates it in C++,
    4-7x faster per call than a Python system. (Drake 1.51.1 aborts in
    ``SymbolicVectorSystem::DoCalcTimeDerivatives`` for a stateless SVS in a
    continuous diagram, so motors, springs and routing are fused into the one
    stateful SVS rather than kept as three C++ blocks.)

The returned sub-diagram exports:

* inputs ``motor_torque`` (m) [Nm], ``joint_angle`` (n) [rad], and with
  hysteresis or guide friction ``joint_velocity`` (``rate_joints``) [rad/s] (no
  joint ports when n = 0, the tendon rig whose far end is fixed);
* outputs ``motor_angle``, ``motor_velocity`` (m), ``motor_state`` (2m),
  ``tendon_force`` (m) [N], ``tendon_stiffness`` (m) [N/m], ``elongation`` (m) [m],
  ``generalized_force`` (n) [Nm] (``-P^T f``), ``applied_torque`` (m) [Nm].

State: ``[theta (m), omega (m)]`` then, with hysteresis, ``z (m)``, then with guide friction
``g (m)`` (compiled drive).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, Demultiplexer, Gain, Multiplexer, SymbolicVectorSystem

from awiwi_drake.components.fused_drive import DriveModel, GuideFrictionModel, TendonDrive_, _variables, drive_laws
from awiwi_drake.components.motor import MotorBank_
from awiwi_drake.components.routing import TendonRouting_
from awiwi_drake.components.spring import SpringBank_, TendonSprings
from awiwi_drake.parameters.components import HysteresisParams, MotorParams

__all__ = ["build_tendon_drive", "TendonDrive", "BACKENDS", "DRIVE_OUTPUTS"]

BACKENDS = ("compiled", "python", "symbolic")
DRIVE_OUTPUTS = ("motor_angle", "motor_velocity", "motor_state", "tendon_force", "tendon_stiffness",
                 "elongation", "generalized_force", "applied_torque")


@dataclass(frozen=True)
class TendonDrive:
    """Handle of a built drive: the sub-diagram and its sizes."""

    diagram: Diagram
    num_tendons: int
    num_joints: int
    backend: str
    hysteresis: bool
    model: DriveModel | None = None

    @property
    def guide_friction(self) -> bool:
        """Whether the drive carries the guide friction state (compiled drive only)."""
        return self.model is not None and self.model.has_guide_friction

    @property
    def num_states(self) -> int:
        if self.model is not None:
            return self.model.num_states - (2 * self.num_joints if self.model.has_link else 0)
        return (3 if self.hysteresis else 2) * self.num_tendons


def build_tendon_drive(*, motor: MotorParams, spring, coupling, offsets=None, backend: str = "compiled",
                       hysteresis: HysteresisParams = HysteresisParams(),
                       motor_pulley_radius: float | None = None, name: str = "tendon_drive",
                       guide_friction: GuideFrictionModel | None = None,
                       rate_joints: int | None = None) -> TendonDrive:
    """Build the motors + springs + routing sub-diagram (see module docstring).

    Parameters
    ----------
    motor : MotorParams
        Shared by all m motors.
    spring : spring law, or one law per tendon
        ``force(x)``/``stiffness(x)`` object (e.g. :func:`tendon_spring`), or a
        :class:`~awiwi_drake.components.spring.TendonSprings` (or a sequence of m laws):
        every backend evaluates tendon ``i`` with its own law.
    coupling : coupling object
        ``h(q)``, ``P(q)``, ``num_tendons``, ``num_joints`` (see :mod:`routing`).
    offsets : (m,) array, optional
        Elongation offsets x0 [m] (pretension with all angles zero).
    backend : {"compiled", "python", "symbolic"}
        Default "compiled" (see the module docstring for the trade-off).
    hysteresis : HysteresisParams
        Spring hysteresis (adds m states and the ``joint_velocity`` input).
    motor_pulley_radius : float, optional
        Transmission radius from elongation to motor angle; defaults to
        ``motor.pulley_radius``. The flexible joint uses 1 (torsional spring).
    name : str
        Name of the sub-diagram.
    guide_friction : GuideFrictionModel, optional
        Guide friction on every tendon path (``backend="compiled"`` only).
    rate_joints : int, optional
        Number of leading coupling joints with a ``joint_velocity`` input (default
        all); the rest (the hand's wrist length offsets) are quasi-static.
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend = {backend!r} is unknown; use one of {', '.join(BACKENDS)}")
    if not isinstance(motor, MotorParams):
        raise ValueError(f"build_tendon_drive: motor must be MotorParams, got {type(motor).__name__}")
    m, n = int(coupling.num_tendons), int(coupling.num_joints)
    r_m = motor.pulley_radius if motor_pulley_radius is None else float(motor_pulley_radius)
    if not r_m > 0:
        raise ValueError(f"build_tendon_drive: motor_pulley_radius = {r_m} must be > 0")
    offsets = np.zeros(m) if offsets is None else np.asarray(offsets, dtype=float)
    if offsets.shape != (m,) or not np.all(np.isfinite(offsets)):
        raise ValueError(f"build_tendon_drive: offsets must be {m} finite numbers [m], got {offsets!r}")
    if isinstance(spring, (list, tuple)):
        spring = TendonSprings(spring)
    per_tendon = isinstance(spring, TendonSprings)
    if per_tendon and len(spring) != m:
        raise ValueError(f"build_tendon_drive: spring has {len(spring)} laws, one per tendon ({m}) expected")
    if per_tendon and spring.uniform and backend != "compiled":
        spring = spring[0]                    # one law for all: the plain bank
        per_tendon = False
    if guide_friction is not None and backend != "compiled":
        raise ValueError(f"build_tendon_drive: guide_friction needs backend='compiled', not {backend!r}")
    if backend == "symbolic" and not getattr(spring, "supports_symbolic", False):
        raise ValueError(f"build_tendon_drive: spring {type(spring).__name__} cannot be used with backend='symbolic' "
                         "(use its calibration polynomial, or backend='python')")
    builder = DiagramBuilder()
    model = None if backend == "python" else DriveModel(
        motor, spring.laws if per_tendon else (spring,) * m, coupling, offsets, r_m, hysteresis, guide_friction,
        rate_joints)
    if backend == "compiled":
        sys_ = builder.AddNamedSystem("drive", TendonDrive_[float](model))
        for i in range(sys_.num_input_ports()):
            builder.ExportInput(sys_.get_input_port(i), sys_.get_input_port(i).get_name())
        for i in range(sys_.num_output_ports()):
            builder.ExportOutput(sys_.get_output_port(i), sys_.get_output_port(i).get_name())
    elif backend == "python":
        _build_python(builder, motor, spring, coupling, offsets, hysteresis, r_m, m, n)
    else:
        # numpy checks the FPU flags after object-array ufuncs; symbolic expressions leave
        # spurious 'invalid value' flags behind, which are meaningless here.
        with np.errstate(invalid="ignore"):
            _build_symbolic(builder, model)
    diagram = builder.Build()
    diagram.set_name(name)
    return TendonDrive(diagram, m, n, backend, bool(hysteresis.enabled), model if backend == "compiled" else None)


def _build_python(b, motor, spring, coupling, offsets, hyst, r_m, m, n):
    same_radius = abs(r_m - motor.pulley_radius) < 1e-15
    motors = b.AddNamedSystem("motors", MotorBank_[float](motor, m, "tendon_force" if same_radius else "load_torque"))
    springs = b.AddNamedSystem("springs", SpringBank_[float](spring, m, hyst))
    routing = b.AddNamedSystem("routing", TendonRouting_[float](coupling, r_m, offsets, bool(hyst.enabled)))
    b.Connect(motors.GetOutputPort("motor_angle"), routing.GetInputPort("motor_angle"))
    b.Connect(routing.GetOutputPort("elongation"), springs.GetInputPort("elongation"))
    b.Connect(springs.GetOutputPort("tendon_force"), routing.GetInputPort("tendon_force"))
    if same_radius:
        b.Connect(springs.GetOutputPort("tendon_force"), motors.GetInputPort("tendon_force"))
    else:
        gain = b.AddNamedSystem("load_gain", Gain(r_m, m))
        b.Connect(springs.GetOutputPort("tendon_force"), gain.get_input_port())
        b.Connect(gain.get_output_port(), motors.GetInputPort("load_torque"))
    b.ExportInput(motors.GetInputPort("motor_torque"), "motor_torque")
    if n > 0:
        b.ExportInput(routing.GetInputPort("joint_angle"), "joint_angle")
    else:  # far end fixed (tendon rig): no joints
        empty = b.AddNamedSystem("no_joints", ConstantVectorSource(np.zeros(0)))
        b.Connect(empty.get_output_port(), routing.GetInputPort("joint_angle"))
    if hyst.enabled and n == 0:
        b.Connect(empty.get_output_port(), routing.GetInputPort("joint_velocity"))
        b.Connect(motors.GetOutputPort("motor_velocity"), routing.GetInputPort("motor_velocity"))
        b.Connect(routing.GetOutputPort("elongation_rate"), springs.GetInputPort("elongation_rate"))
    elif hyst.enabled:
        b.Connect(motors.GetOutputPort("motor_velocity"), routing.GetInputPort("motor_velocity"))
        b.Connect(routing.GetOutputPort("elongation_rate"), springs.GetInputPort("elongation_rate"))
        b.ExportInput(routing.GetInputPort("joint_velocity"), "joint_velocity")
    b.ExportOutput(motors.GetOutputPort("motor_angle"), "motor_angle")
    b.ExportOutput(motors.GetOutputPort("motor_velocity"), "motor_velocity")
    b.ExportOutput(motors.GetOutputPort("state"), "motor_state")
    b.ExportOutput(springs.GetOutputPort("tendon_force"), "tendon_force")
    b.ExportOutput(springs.GetOutputPort("tendon_stiffness"), "tendon_stiffness")
    b.ExportOutput(routing.GetOutputPort("elongation"), "elongation")
    if n > 0:
        b.ExportOutput(routing.GetOutputPort("generalized_force"), "generalized_force")
    b.ExportOutput(motors.GetOutputPort("applied_torque"), "applied_torque")


def _build_symbolic(b, model: DriveModel):
    """:func:`drive_laws` of ``model`` (no link, no guide friction) on symbolic variables, in one C++ system."""
    m, n, hyst = model.num_tendons, model.num_joints, model.has_hysteresis
    s_v, s = _variables("s", model.num_states)           # theta, omega, (z)
    u_v, u = _variables("u", m)
    q_v, q = _variables("q", n)
    qd_v, qd = _variables("qdot", n) if hyst else ([], None)
    laws = drive_laws(model, s, u, q, qd)
    outputs = [*s[:2 * m], *(e for k in ("tendon_force", "tendon_stiffness", "elongation", "generalized_force",
                                         "applied_torque") for e in np.asarray(laws[k], dtype=object))]
    svs = b.AddNamedSystem("drive", SymbolicVectorSystem(state=s_v, input=u_v + q_v + qd_v,
                                                         dynamics=list(laws["derivatives"]), output=outputs))
    in_names = ["motor_torque", "joint_angle"] + (["joint_velocity"] if hyst else [])
    in_sizes = [m, n] + ([n] if hyst else [])
    in_ports = [(nm, sz) for nm, sz in zip(in_names, in_sizes) if sz > 0]  # no joints: tendon rig
    if len(in_ports) == 1:
        b.ExportInput(svs.get_input_port(), "motor_torque")
    else:
        mux = b.AddNamedSystem("inputs", Multiplexer([sz for _, sz in in_ports]))
        b.Connect(mux.get_output_port(), svs.get_input_port())
        for i, (nm, _) in enumerate(in_ports):
            b.ExportInput(mux.get_input_port(i), nm)
    out_names = ["motor_angle", "motor_velocity", "tendon_force", "tendon_stiffness", "elongation",
                 "generalized_force", "applied_torque"]
    out_sizes = [m, m, m, m, m, n, m]
    keep = [(nm, sz) for nm, sz in zip(out_names, out_sizes) if sz > 0]
    demux = b.AddNamedSystem("outputs", Demultiplexer([sz for _, sz in keep]))
    b.Connect(svs.get_output_port(), demux.get_input_port())
    for i, (nm, _) in enumerate(keep):
        b.ExportOutput(demux.get_output_port(i), nm)
    state_mux = b.AddNamedSystem("motor_state_mux", Multiplexer([m, m]))
    b.Connect(demux.get_output_port(0), state_mux.get_input_port(0))
    b.Connect(demux.get_output_port(1), state_mux.get_input_port(1))
    b.ExportOutput(state_mux.get_output_port(), "motor_state")
