"""Motor model (thesis ch. 3): laws and the vectorised ``MotorBank_`` system.

Dynamics at the output shaft (3.5)::

    B thdd = sat(u) + tau_fric(thd) + tau_ripple(th) - tau_load

with the reflected inertia (3.1), the friction law (3.8) (Table 3.3) and the
position-dependent ripple of the motor-shaft bearing (``gear_ratio`` periods
per output revolution) and of the output bearing (one period per revolution).
``tau_load = r_m f`` when the load is a tendon force.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake._math import clip
from awiwi_drake.components.friction import atan_friction
from awiwi_drake.parameters.components import MotorParams

__all__ = [
    "reflected_inertia",
    "motor_friction_torque",
    "motor_ripple_torque",
    "saturate_torque",
    "motor_drive_torque",
    "motor_acceleration",
    "MotorBank_",
    "MotorBank",
]


def reflected_inertia(motor_inertia: float, gearbox_inertia: float, gear_ratio: float) -> float:
    """Total inertia at the output shaft (3.1): ``B = B_motor alpha^-2 + B_gearbox``.

    ``gear_ratio`` is input/output speed (100 for the Awiwi harmonic drive), so
    ``alpha_gear = 1/gear_ratio`` and ``alpha^-2 = gear_ratio^2``.
    """
    if motor_inertia < 0 or gearbox_inertia < 0:
        raise ValueError("reflected_inertia: motor_inertia and gearbox_inertia must be >= 0 [kg m^2]")
    if gear_ratio <= 0:
        raise ValueError(f"reflected_inertia: gear_ratio = {gear_ratio} must be > 0")
    return motor_inertia * gear_ratio ** 2 + gearbox_inertia


def motor_friction_torque(omega, p: MotorParams):
    """Friction torque acting on the motor (3.8), Table 3.3, plus linear damping.

    ``tau_fric = -(gamma2 atan(gamma1 w) + gamma3 w) - d w`` (zero when
    ``p.friction`` is off, except the damping ``d``). Works element-wise for
    float, AutoDiffXd and Expression arrays.
    """
    tau = -p.damping * omega
    if p.friction:
        tau = tau + atan_friction(omega, p.coulomb_torque, p.friction_slope, p.viscous_friction)
    return tau


def motor_ripple_torque(theta, p: MotorParams):
    """Position-dependent ripple torque (3.5), zero when ``p.ripple`` is off.

    ``a_m sin(N th + phi_m) + a_o sin(th + phi_o)`` with ``N = gear_ratio``:
    the motor-shaft bearing repeats ``N`` times per output revolution, the output
    bearing once.
    """
    if not p.ripple:
        return 0.0 * theta
    return (p.ripple_motor_amplitude * np.sin(p.gear_ratio * theta + p.ripple_motor_phase)
            + p.ripple_output_amplitude * np.sin(theta + p.ripple_output_phase))


def saturate_torque(u, p: MotorParams):
    """Commanded torque clipped to ``+-torque_limit`` when ``p.saturation`` is on."""
    if not p.saturation:
        return u
    return clip(u, -p.torque_limit, p.torque_limit)


def motor_drive_torque(theta, omega, u, p: MotorParams):
    """The torque of (3.5) on the output shaft apart from the load: ``sat(u) + tau_fric + tau_ripple`` [Nm]."""
    tau = saturate_torque(u, p)
    if p.friction or p.damping:
        tau = tau + motor_friction_torque(omega, p)
    if p.ripple:
        tau = tau + motor_ripple_torque(theta, p)
    return tau


def motor_acceleration(theta, omega, u, load_torque, p: MotorParams):
    """Output-shaft acceleration of (3.5): ``(sat(u) + tau_fric + tau_ripple - load) / B``."""
    return (motor_drive_torque(theta, omega, u, p) - load_torque) / p.inertia


@TemplateSystem.define("MotorBank_")
def MotorBank_(T):
    """N geared motors in one system (thesis ch. 3).

    State ``[theta_1..theta_N, omega_1..omega_N]`` (output shaft, rad and rad/s).

    Input ports
    -----------
    motor_torque : (N,) [Nm]
        Commanded torque at the output shaft (saturated when enabled).
    tendon_force : (N,) [N]   (``load_input="tendon_force"``, default)
        Tendon tension; load torque ``r_m f``.
    load_torque : (N,) [Nm]   (``load_input="load_torque"``)
        Load torque opposing the motor.

    Output ports
    ------------
    motor_angle, motor_velocity : (N,)
    state : (2N,)
    applied_torque : (N,) [Nm]
        The commanded torque after saturation.
    """

    class Impl(LeafSystem_[T]):
        def _construct(self, params: MotorParams = MotorParams(), num_motors: int = 1,
                       load_input: str = "tendon_force", converter=None):
            LeafSystem_[T].__init__(self, converter)
            if not isinstance(params, MotorParams):
                raise ValueError(f"MotorBank: params must be MotorParams, got {type(params).__name__}")
            if int(num_motors) != num_motors or num_motors < 1:
                raise ValueError(f"MotorBank: num_motors = {num_motors!r} must be a positive integer")
            if load_input not in ("tendon_force", "load_torque"):
                raise ValueError(f"MotorBank: load_input = {load_input!r} must be 'tendon_force' or 'load_torque'")
            n = int(num_motors)
            self.params, self.num_motors, self.load_input = params, n, load_input
            self._load_gain = params.pulley_radius if load_input == "tendon_force" else 1.0
            # All misc (z) state, like the SymbolicVectorSystem backend, so a diagram orders its
            # state [plant q, plant v, theta, omega] for both backends.
            self.DeclareContinuousState(2 * n)
            self._u = self.DeclareVectorInputPort("motor_torque", n)
            self._f = self.DeclareVectorInputPort(load_input, n)
            state = {self.all_state_ticket()}
            self.DeclareVectorOutputPort("motor_angle", n, self._calc_angle, prerequisites_of_calc=state)
            self.DeclareVectorOutputPort("motor_velocity", n, self._calc_velocity, prerequisites_of_calc=state)
            self.DeclareVectorOutputPort("state", 2 * n, self._calc_state, prerequisites_of_calc=state)
            self.DeclareVectorOutputPort("applied_torque", n, self._calc_applied,
                                         prerequisites_of_calc={self._u.ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.params, other.num_motors, other.load_input, converter=converter)

        def _x(self, context):
            return context.get_continuous_state_vector().CopyToVector()

        def DoCalcTimeDerivatives(self, context, derivatives):
            n = self.num_motors
            x = self._x(context)
            theta, omega = x[:n], x[n:]
            u = self._u.Eval(context)
            load = self._load_gain * self._f.Eval(context)
            acc = motor_acceleration(theta, omega, u, load, self.params)
            derivatives.get_mutable_vector().SetFromVector(np.concatenate([omega, acc]))

        def _calc_angle(self, context, out):
            out.SetFromVector(self._x(context)[: self.num_motors])

        def _calc_velocity(self, context, out):
            out.SetFromVector(self._x(context)[self.num_motors:])

        def _calc_state(self, context, out):
            out.SetFromVector(self._x(context))

        def _calc_applied(self, context, out):
            out.SetFromVector(saturate_torque(self._u.Eval(context), self.params))

    return Impl


MotorBank = MotorBank_[None]
