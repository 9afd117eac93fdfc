"""Joint friction (disturbance) observer and compensation (thesis ch. 9), link-side friction law.

Observer (9.2), written for a link of inertia ``J`` whose known driving torque
``tau_a`` (the measured joint torque, minus modelled damping) is disturbed by an
unknown torque ``d`` (friction, contact):

    J w' = tau_a + d                      (link)
    J w_hat' = tau_a + d_hat              (model copy)
    d_hat = L J (w - w_hat)               (Luenberger correction, (9.2))

so that ``d_hat' = L (d - d_hat)``: the estimate is ``d`` low-pass filtered at
``L`` [rad/s] (the "filtered version of the real friction" of section 9.1).
The thesis writes the friction torque with the opposite sign
(``tau_fric = -d``); compensation adds ``-d_hat`` to the desired joint torque
(``u = u_c + tau_fric_hat``).

:func:`observer_rate` is the law (float, AutoDiffXd); :class:`DisturbanceObserver_`
the TemplateSystem; the impedance backstepping controller embeds the same law
to estimate the external torque that its design (15.62) formally requires.
:class:`LinkFriction_` applies the smooth Stribeck law
(:func:`~awiwi_drake.components.friction.stribeck_friction`) to the link of the test joint.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake.components.friction import stribeck_friction
from awiwi_drake.parameters.hand_control import FrictionObserverParams, LinkFrictionParams

__all__ = ["observer_rate", "DisturbanceObserver_", "DisturbanceObserver", "friction_tracking_run", "chattering",
           "LinkFriction_", "LinkFriction"]


def observer_rate(w_hat, w, known_torque, inertia: float, gain: float):
    """``(w_hat', d_hat)`` of the observer (9.2) for velocity ``w`` and known torque ``tau_a``."""
    d_hat = gain * inertia * (w - w_hat)
    return (known_torque + d_hat) / inertia, d_hat


@TemplateSystem.define("DisturbanceObserver_")
def DisturbanceObserver_(T):
    class Impl(LeafSystem_[T]):
        """Observer (9.2). Inputs ``link_velocity`` (1) [rad/s], ``joint_torque`` (1) [Nm] (known
        driving torque); output ``disturbance_estimate`` (1) [Nm] (``-tau_fric_hat``); state ``w_hat``.
        """

        def _construct(self, inertia: float, params: FrictionObserverParams | None = None, damping: float = 0.0,
                       converter=None):
            LeafSystem_[T].__init__(self, converter)
            if not inertia > 0:
                raise ValueError(f"DisturbanceObserver: inertia = {inertia} must be > 0 [kg m^2]")
            self.inertia, self.params, self.damping = float(inertia), params or FrictionObserverParams(), float(damping)
            self.DeclareContinuousState(1)
            self.DeclareVectorInputPort("link_velocity", 1)
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


@TemplateSystem.define("LinkFriction_")
def LinkFriction_(T):
    class Impl(LeafSystem_[T]):
        """Link-side stick-slip friction: input ``link_velocity`` (1), output ``friction_torque`` (1) [Nm]."""

        def _construct(self, params: LinkFrictionParams | None = None, converter=None):
            LeafSystem_[T].__init__(self, converter)
            self.params = params or LinkFrictionParams()
            self.DeclareVectorInputPort("link_velocity", 1)
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


def friction_tracking_run(*, compensate: bool, amplitude: float = 0.3, frequency: float = 0.5,
                          t_final: float = 4.0, friction: LinkFrictionParams | None = None,
                          observer: FrictionObserverParams | None = None, gains=None, dt: float = 1e-3):
    """Fig 9.3: slow sinusoidal tracking of the antagonistic joint with link-side stick-slip friction.

    The joint rig's link gets the friction torque of :class:`LinkFriction` on its
    ``external_torque`` input; the antagonistic backstepping impedance controller estimates the
    disturbance with the observer (9.2) and, with ``compensate=True``, cancels it (``u = u_c +
    tau_fric_hat``). Returns a :class:`~awiwi_drake.control.backstepping_studies.BacksteppingRun`
    with ``extra["friction"]`` (true) and ``extra["friction_estimate"]``.
    """
    import math
    from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
    from pydrake.systems.framework import DiagramBuilder
    from awiwi_drake.control.backstepping_studies import BacksteppingRun, impedance_controller
    from awiwi_drake.control.base import closed_loop
    from awiwi_drake.parameters.backstepping import AntagonisticBacksteppingGains
    from awiwi_drake.rigs import joint_rig
    from awiwi_drake.parameters.rigs import JointRigParams
    fp = friction or LinkFrictionParams()
    rig = joint_rig(params=JointRigParams().replace(link_inertia=fp.test_joint_inertia))
    g = gains or AntagonisticBacksteppingGains()
    obs = observer or FrictionObserverParams()
    from awiwi_drake.parameters.backstepping import ImpedanceBacksteppingGains
    ig = ImpedanceBacksteppingGains(stiffness=g.stiffness, damping=g.damping, k3=g.k3, k4=g.k4, observer_gain=obs.gain)
    ctrl = impedance_controller(rig, ig, pretension=g.pretension, reference_derivatives=4, compensate=compensate)
    loop = closed_loop(rig, ctrl, rate_hz=None)
    b = DiagramBuilder()
    cl = b.AddNamedSystem("loop", loop.diagram)
    fr = b.AddNamedSystem("link_friction", LinkFriction(fp))
    b.Connect(cl.GetOutputPort("link_velocity"), fr.get_input_port())
    b.Connect(fr.get_output_port(), cl.GetInputPort("external_torque"))
    b.ExportInput(cl.GetInputPort("link_angle_reference"), "link_angle_reference")
    diagram = b.Build()
    ctx = diagram.CreateDefaultContext()
    op = rig.operating_point(pretension=g.pretension)
    loop.diagram.GetSubsystemByName("rig").GetMyMutableContextFromRoot(ctx).SetContinuousState(op.state)
    w = 2 * math.pi * frequency
    ref_port = diagram.GetInputPort("link_angle_reference")

    def ref(t):
        s, c = math.sin(w * t), math.cos(w * t)
        return [amplitude * s, amplitude * w * c, -amplitude * w ** 2 * s, -amplitude * w ** 3 * c, amplitude * w ** 4 * s]

    ref_port.FixValue(ctx, ref(0.0))
    sim = Simulator(diagram, ctx)
    ResetIntegratorFromFlags(sim, "runge_kutta3", dt)
    sim.get_mutable_integrator().set_target_accuracy(1e-6)
    c_sys = loop.diagram.GetSubsystemByName("controller")
    rig_sys = loop.diagram.GetSubsystemByName("rig")
    ts = np.arange(int(round(t_final / dt)) + 1) * dt
    X, U, V, R, F, E = [], [], [], [], [], []
    for t in ts:
        if t > 0:
            sim.AdvanceTo(t)
        ref_port.FixValue(ctx, ref(t))
        x = rig_sys.GetMyContextFromRoot(ctx).get_continuous_state_vector().CopyToVector()
        if not np.all(np.isfinite(x)):
            raise RuntimeError(f"friction_tracking_run: state not finite at t = {t:.4g} s")
        cctx = c_sys.GetMyContextFromRoot(ctx)
        X.append(x)
        U.append(np.array(c_sys.GetOutputPort("motor_torque").Eval(cctx)))
        V.append(c_sys.GetOutputPort("lyapunov").Eval(cctx)[0])
        R.append(ref(t)[0])
        F.append(fr.get_output_port().Eval(fr.GetMyContextFromRoot(ctx))[0])
        E.append(c_sys.GetOutputPort("external_torque_estimate").Eval(cctx)[0])
    return BacksteppingRun("with compensation" if compensate else "without compensation", ts, np.array(X),
                           np.array(U), np.array(V), np.array(R), np.array(F),
                           dict(friction=np.array(F), friction_estimate=np.array(E)))


def chattering(run, *, after: float = 0.0) -> float:
    """Mean absolute rate of change of the motor torques [Nm/s] (total variation per second)."""
    m = run.t >= after
    u = run.command[m]
    return float(np.sum(np.abs(np.diff(u, axis=0))) / (run.t[m][-1] - run.t[m][0]))
