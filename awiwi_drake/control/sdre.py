"""State-dependent Riccati equation control (ch. 14).

The pointwise-linear form ``xdot = A(x) x + B(x) u`` of (14.3) is taken as the
Jacobian of the rig dynamics at the current measured state, evaluated with
Drake's automatic differentiation of the rig diagram (:class:`RigJacobian`);
this is the linearisation w.r.t. the motor position of (14.8) for the tendon
and the stiffness factorisation (14.10) with the local (tangent) stiffness for
the flexible joint.  The gain ``K = R^-1 B^T S`` ((14.4)-(14.5), Drake's
``LinearQuadraticRegulator``) is recomputed at ``update_rate`` (~200 Hz,
section 14.4) and held in the controller's discrete state; between updates
the law is ``u = u_ref(r) - K (x - x_ref(r))``.  At the linearisation point
the SDRE gain equals the LQR gain (tested).

With ``update_rate=None`` the gain stays at its design value: the fixed-gain
LQR comparator of Fig 14.3-14.5.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, InitializeAutoDiff
from pydrake.systems.framework import LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake._math import is_float
from awiwi_drake.control.base import COMMAND_PORT, REFERENCE_SUFFIX, check_gain, check_gains
from awiwi_drake.control.linear import linearize_rig, reference_maps
from awiwi_drake.control.lqr import expand_q, lqr_gain
from awiwi_drake.parameters.control import SdreJointParams, SdreTendonParams

__all__ = ["RigJacobian", "TendonSdreModel", "LinearReferenceModel", "SdreController_", "SdreController",
           "tendon_sdre_controller", "joint_sdre_controller"]


class RigJacobian:
    """``(A, B)`` of a rig's continuous dynamics w.r.t. (state, motor_torque) by Drake autodiff."""

    def __init__(self, rig: Any):
        self.diagram = rig.diagram.ToAutoDiffXd()
        self.context = self.diagram.CreateDefaultContext()
        self.n = self.context.num_continuous_states()
        self.port = self.diagram.GetInputPort(COMMAND_PORT)
        self.m = self.port.size()
        self._others = [self.diagram.get_input_port(i) for i in range(self.diagram.num_input_ports())
                        if self.diagram.get_input_port(i).get_name() != COMMAND_PORT]

    def __call__(self, x, u, external: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        n, m = self.n, self.m
        xu = InitializeAutoDiff(np.concatenate([np.asarray(x, float).reshape(-1), np.asarray(u, float).reshape(-1)]))
        xu = xu.reshape(-1)
        self.context.SetContinuousState(xu[:n])
        self.port.FixValue(self.context, xu[n:])
        for p in self._others:
            p.FixValue(self.context, np.array([AutoDiffXd(float(external))] * p.size()))
        xdot = self.diagram.EvalTimeDerivatives(self.context).CopyToVector()
        J = ExtractGradient(xdot)
        return J[:, :n], J[:, n:]


class TendonSdreModel:
    """Tendon rig ``x = [theta, omega]``; equilibrium ``theta_ref = f^-1(f_ref)``, ``u_ref = r_m f_ref``."""

    reference = "tendon_force"

    def __init__(self, fmap, pulley_radius: float):
        self.fmap = fmap
        self.r_m = check_gain("pulley_radius", pulley_radius, owner="tendon sdre")
        self.inputs = {"tendon_force_reference": 1, "motor_angle": 1, "motor_velocity": 1}

    def state(self, values):
        return np.array([values["motor_angle"][0], values["motor_velocity"][0]])

    def equilibrium(self, r):
        self.fmap.check_force(r, "tendon_force_reference")  # ValueError outside the force table [0, f_max]
        th = self.fmap.theta_of_force(r)
        zero = th * 0.0
        return np.array([th, zero]), np.array([self.r_m * r])


class LinearReferenceModel:
    """Joint rigs: equilibrium family ``x0 + Nx (r - r0)``, ``u0 + Nu (r - r0)`` of the linearisation."""

    reference = "link_angle"

    def __init__(self, lin):
        self.Nx, self.Nu = reference_maps(lin.A, lin.B, lin.C["link_angle"])
        self.x0, self.u0 = lin.x0, lin.u0
        self.r0 = float(np.ravel(lin.y0["link_angle"])[0])
        self.inputs = {"link_angle_reference": 1, "state": lin.A.shape[0]}

    def state(self, values):
        return values["state"]

    def equilibrium(self, r):
        dr = r - self.r0
        return self.x0 + self.Nx * dr, self.u0 + self.Nu * dr


@TemplateSystem.define("SdreController_", T_list=[float, AutoDiffXd])
def SdreController_(T):
    """SDRE state feedback with the gain held in discrete state, refreshed periodically."""

    class Impl(LeafSystem_[T]):
        def _construct(self, model, jacobian: RigJacobian, Q, R, update_period: float | None, K0,
                       name: str = "sdre", converter=None):
            LeafSystem_[T].__init__(self, converter)
            self.model, self.jacobian, self.name_ = model, jacobian, name
            self.Q = check_gains("Q", Q, owner=name)
            self.R = np.atleast_2d(check_gains("R", R, owner=name))
            if update_period is not None:
                check_gain("update_period", update_period, owner=name)
            self.update_period = update_period
            self.K0 = np.atleast_2d(check_gains("K0", K0, owner=name))
            m, n = self.K0.shape
            self.m, self.n = m, n
            self._ports = {nm: self.DeclareVectorInputPort(nm, sz) for nm, sz in model.inputs.items()}
            self.gain_index = self.DeclareDiscreteState(self.K0.reshape(-1))
            tickets = {p.ticket() for p in self._ports.values()} | {self.discrete_state_ticket(self.gain_index)}
            self.DeclareVectorOutputPort(COMMAND_PORT, m, self._calc, prerequisites_of_calc=tickets)
            self.DeclareStateOutputPort("gain", self.gain_index)
            if update_period is not None:
                self.DeclarePeriodicDiscreteUpdateEvent(update_period, 0.0, self._update)
            self.set_name(name)

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.model, other.jacobian, other.Q, other.R, other.update_period, other.K0,
                            other.name_, converter=converter)

        def _values(self, context):
            return {nm: p.Eval(context) for nm, p in self._ports.items()}

        def gain_at(self, x, u) -> np.ndarray:
            """The SDRE gain at state ``x`` with input ``u`` (float)."""
            A, B = self.jacobian(x, u)
            return lqr_gain(A, B, self.Q, self.R)[0]

        def _update(self, context, discrete_state):
            vals = self._values(context)
            x = self.model.state(vals)
            r = vals[self.model.reference + REFERENCE_SUFFIX][0]
            _, u_ref = self.model.equilibrium(r)
            xf = np.array([v if is_float(v) else v.value() for v in np.asarray(x).reshape(-1)], float)
            uf = np.array([v if is_float(v) else v.value() for v in np.asarray(u_ref).reshape(-1)], float)
            K = self.gain_at(xf, uf)
            k = K.reshape(-1)
            if T != float:
                k = np.array([AutoDiffXd(float(v)) for v in k], dtype=object)
            discrete_state.set_value(self.gain_index, k)

        def _calc(self, context, output):
            vals = self._values(context)
            K = context.get_discrete_state(self.gain_index).CopyToVector().reshape(self.m, self.n)
            x = self.model.state(vals)
            r = vals[self.model.reference + REFERENCE_SUFFIX][0]
            x_ref, u_ref = self.model.equilibrium(r)
            output.SetFromVector(np.asarray(u_ref - K @ (x - x_ref)).reshape(-1))

    return Impl


SdreController = SdreController_[None]


def tendon_sdre_controller(rig: Any, params: SdreTendonParams | None = None, *, design_force: float = 30.0,
                           fixed: bool = False, fmap=None):
    """Registered factory ``tendon-sdre`` (Table 14.1); ``fixed=True``: LQR gains frozen at ``design_force``."""
    from awiwi_drake.control.tendon_force import _motor, force_map
    p = params or SdreTendonParams()
    fmap = fmap or force_map(rig)
    model = TendonSdreModel(fmap, _motor(rig).pulley_radius)
    jac = RigJacobian(rig)
    Q, R = np.diag(p.q_diag), np.array([[p.r]])
    x0, u0 = model.equilibrium(design_force)
    K0 = lqr_gain(*jac(x0, u0), Q, R)[0]
    return SdreController(model, jac, Q, R, None if fixed else 1.0 / p.update_rate, K0,
                          "tendon_lqr_fixed" if fixed else "tendon_sdre")


def joint_sdre_controller(rig: Any, params: SdreJointParams | None = None, *, op: Any = None, fixed: bool = False):
    """Registered factory ``sdre`` for the joint rigs (Table 14.2); ``fixed=True``: LQR at ``op``."""
    p = params or SdreJointParams()
    lin = linearize_rig(rig, op, outputs=("state", "link_angle"))
    model = LinearReferenceModel(lin)
    jac = RigJacobian(rig)
    n, m = lin.B.shape
    Q, R = expand_q(p.q_diag, n), p.r * np.eye(m)
    K0 = lqr_gain(lin.A, lin.B, Q, R)[0]
    return SdreController(model, jac, Q, R, None if fixed else 1.0 / p.update_rate, K0,
                          "joint_lqr_fixed" if fixed else "sdre")
