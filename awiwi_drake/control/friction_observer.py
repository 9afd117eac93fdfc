"""Joint friction (disturbance) observer and compensation (thesis ch. 9), link-side friction law.

Observer (9.2), written for a link of inertia ``J`` whose known driving torque
``tau_a`` (the measured joint torque, minus modelled damping) is disturbed by an
unknown torque ``d`` (friction, contact):

    J w' = tau_a + d                      (link)
    J w_hat' = tau_a + d_hat              (model copy)
    d_hat = L J (w - w_hat)               (Luenberger correction, (9.2))

so that ``d_hat' = L (d - d_hat)``: the estimate is ``d`` low-pass filtered at
``L`` [rad/s] (the "filtered version of the real friction" of section 9.1).

Sampled at the control period ``h`` (the hand's chain, :func:`observer_step`): the model copy integrated
exactly over the period with its torque ``tau_a,k + d_hat_k`` held (the chain holds everything it computes at
a sample, as the plant's zero-order hold holds the motor torques),

    w_hat_k+1 = w_hat_k + h (tau_a,k + d_hat_k) / J,      d_hat_k = L J (w_k - w_hat_k),

so the estimation error ``e = w - w_hat`` of a link driven by the same held torques plus a constant ``d``
obeys ``e_k+1 = (1 - L h) e_k + h d / J``: pole ``1 - L h`` (0.9333 at 200 rad/s and 3 kHz; the continuous
pole mapped, ``exp(-L h)``, is 0.9355), stable for ``L h < 2``, and ``d_hat_k = d (1 - (1 - L h)^k)``, no bias
(holding ``w`` instead, the exact solution with ``w`` constant over the period, would be biased by
``L h / (1 - exp(-L h))``, 3.4 %, whenever the link accelerates).
The thesis writes the friction torque with the opposite sign
(``tau_fric = -d``); compensation adds ``-d_hat`` to the desired joint torque
(``u = u_c + tau_fric_hat``).

:func:`observer_rate` is the law (float, AutoDiffXd); :class:`DisturbanceObserver_`
the TemplateSystem; the impedance backstepping controller embeds the same law
to estimate the external torque that its design (15.62) formally requires.
:class:`LinkFriction_` applies the smooth Stribeck law
(:func:`~awiwi_drake.components.friction.stribeck_friction`) to the link of the test joint.
The Fig 9.3 run is :mod:`awiwi_drake.reproductions.ch09_friction_observer`.
"""

from __future__ import annotations

import sys

import numpy as np
from pydrake.systems.framework import LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake.components.friction import stribeck_friction
from awiwi_drake.parameters.hand_control import FrictionObserverParams, LinkFrictionParams

__all__ = ["observer_rate", "observer_step", "DisturbanceObserver_", "DisturbanceObserver", "LinkFriction_", "LinkFriction",
           "with_link_friction"]


def observer_rate(w_hat, w, known_torque, inertia, gain, inertia_inverse=None):
    """``(w_hat', d_hat)`` of the observer (9.2) for velocity ``w`` and known torque ``tau_a``.  ``inertia``: a
    number or one per DoF (decoupled links), or a ``k x k`` inertia matrix ``J`` (coupled links, e.g. a finger's DoF:
    ``d_hat = L J (w - w_hat)``, ``w_hat' = J^-1 (tau_a + d_hat)``; the error still obeys ``d_hat' = L (d - d_hat)``,
    where a diagonal model would count the off-diagonal inertial torques ``J_off w'`` into ``d``).
    ``inertia_inverse``: ``J^-1`` when the caller holds a constant ``J`` (computed here otherwise)."""
    if np.ndim(inertia) == 2:
        d_hat = gain * (inertia @ (w - w_hat))
        Jinv = np.linalg.inv(inertia) if inertia_inverse is None else inertia_inverse
        return Jinv @ (known_torque + d_hat), d_hat
    d_hat = gain * inertia * (w - w_hat)
    return (known_torque + d_hat) / inertia, d_hat


def observer_step(w_hat, w, known_torque, inertia, gain: float, period: float, inertia_inverse=None):
    """``(w_hat_k+1, d_hat_k)``: the observer (9.2) over one period ``h``, its model copy integrated with the torque
    ``tau_a,k + d_hat_k`` held (module docstring): ``w_hat + h w_hat'`` with :func:`observer_rate`'s rate."""
    rate, d_hat = observer_rate(w_hat, w, known_torque, inertia, gain, inertia_inverse)
    return w_hat + period * rate, d_hat


@TemplateSystem.define("DisturbanceObserver_", scope=sys.modules[__name__])
def DisturbanceObserver_(T):
    class Impl(LeafSystem_[T]):
        """Observer (9.2). Inputs ``joint_velocity`` (1) [rad/s], ``joint_torque`` (1) [Nm] (known
        driving torque); output ``disturbance_estimate`` (1) [Nm] (``-tau_fric_hat``); state ``w_hat``.
        """

        def _construct(self, inertia: float, params: FrictionObserverParams | None = None, damping: float = 0.0,
                       converter=None):
            LeafSystem_[T].__init__(self, converter)
            if not inertia > 0:
                raise ValueError(f"DisturbanceObserver: inertia = {inertia} must be > 0 [kg m^2]")
            self.inertia, self.params, self.damping = float(inertia), params or FrictionObserverParams(), float(damping)
            self.DeclareContinuousState(1)
            self.DeclareVectorInputPort("joint_velocity", 1)
            self.DeclareVectorInputPort("joint_torque", 1)
            self.DeclareVectorOutputPort("disturbance_estimate", 1, self._calc,
                                         prerequisites_of_calc={self.all_state_ticket(),
                                                                self.get_input_port(0).ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.inertia, other.params, other.damping, converter=converter)

        def _rate(self, context):
            w_hat = context.get_continuous_state_vector().GetAtIndex(0)
            w = self.get_input_port(0).Eval(context)[0]
            tau = self.get_input_port(1).Eval(context)[0] - self.damping * w
            return observer_rate(w_hat, w, tau, self.inertia, self.params.gain)

        def _calc(self, context, output):
            w_hat = context.get_continuous_state_vector().GetAtIndex(0)
            w = self.get_input_port(0).Eval(context)[0]
            output.SetAtIndex(0, self.params.gain * self.inertia * (w - w_hat))

        def DoCalcTimeDerivatives(self, context, derivatives):
            derivatives.get_mutable_vector().SetAtIndex(0, self._rate(context)[0])

    return Impl


DisturbanceObserver = DisturbanceObserver_[None]


@TemplateSystem.define("LinkFriction_", scope=sys.modules[__name__])
def LinkFriction_(T):
    class Impl(LeafSystem_[T]):
        """Link-side stick-slip friction: input ``joint_velocity`` (1), output ``friction_torque`` (1) [Nm]."""

        def _construct(self, params: LinkFrictionParams | None = None, converter=None):
            LeafSystem_[T].__init__(self, converter)
            self.params = params or LinkFrictionParams()
            self.DeclareVectorInputPort("joint_velocity", 1)
            self.DeclareVectorOutputPort("friction_torque", 1, self._calc,
                                         prerequisites_of_calc={self.get_input_port(0).ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.params, converter=converter)

        def _calc(self, context, output):
            p = self.params
            output.SetAtIndex(0, stribeck_friction(self.get_input_port(0).Eval(context)[0], p.coulomb, p.static,
                                                   p.stribeck_velocity, p.smoothing_velocity, p.viscous))

    return Impl


LinkFriction = LinkFriction_[None]


def with_link_friction(loop_diagram, params: LinkFrictionParams | None = None):
    """``(diagram, loop_system, friction_system)``: a closed loop whose link gets the stick-slip friction
    of :class:`LinkFriction` on its ``external_torque`` input (feedback from ``joint_velocity``); the
    loop's ``joint_angle_reference`` and every loop output are exported under the same names, the
    friction torque [Nm] as ``link_friction``."""
    from pydrake.systems.framework import DiagramBuilder
    b = DiagramBuilder()
    cl = b.AddNamedSystem("loop", loop_diagram)
    fr = b.AddNamedSystem("link_friction", LinkFriction(params))
    b.Connect(cl.GetOutputPort("joint_velocity"), fr.get_input_port())
    b.Connect(fr.get_output_port(), cl.GetInputPort("external_torque"))
    b.ExportInput(cl.GetInputPort("joint_angle_reference"), "joint_angle_reference")
    for i in range(loop_diagram.num_output_ports()):
        b.ExportOutput(cl.get_output_port(i), loop_diagram.get_output_port(i).get_name())
    b.ExportOutput(fr.get_output_port(), "link_friction")
    return b.Build(), cl, fr


