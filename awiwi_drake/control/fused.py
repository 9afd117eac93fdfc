"""The hand's sampled control chain as ONE discrete system (the fast path :func:`~awiwi_drake.control.closed_loop`
builds for fingers and the hand).

The blocks stay the reference (users compose them, the registry builds them): the rig's link estimator
(:class:`~awiwi_drake.hand.estimation.LinkPositionEstimator_` and its velocity filter), the joint stage
(:class:`~awiwi_drake.control.joint_stage.JointStage_`), the (7.6) distribution
(:class:`~awiwi_drake.control.force_distribution.TendonForceDistribution_`) or the sharing (15.88), the tendon path
velocity and the tendon force law (10.2) (or any static law on the estimated joint state, e.g. the 15.5
backstepping).  As ~15 leaf systems the framework around them costs as much as their work (README, "The hand under
its control chain"); :class:`FusedChain_` holds all their states and evaluates per period exactly what the composed
loop evaluates, by calling the same objects' context-free methods:

* at the sample (one cache entry): the estimate ``q_k`` (:meth:`LinkPositionEstimator_.estimate`), the filtered
  velocity ``qdot_k = C z_k + D q_k``, the stage's ``tau_k`` (plus the sampled (9.2) observer's compensation) and
  the command ``u_k`` from the distribution's state ``f_ref,k`` (or the sharing of ``tau_k``; a law with held
  gains, the tendon SDRE, reads them from this system's state, re-solved by its own periodic event);
* the periodic update stores ``q_k``, the filter state and ``f_ref,k+1`` (:meth:`TendonForceDistribution_.step`).

So it equals the composed loop (tests/test_fused_chain.py, 1e-12).  Scalar types float and AutoDiffXd; not
symbolic (the estimator and the distribution branch on values).  A chain with continuous state or a user-given
estimator or sensor model is closed as the composed blocks.
"""

from __future__ import annotations

import sys

import numpy as np
from pydrake.autodiffutils import AutoDiffXd
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem_, ValueProducer
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake._math import scalar_value
from awiwi_drake.control.force_distribution import TendonForceDistribution_
from awiwi_drake.hand.estimation import LinkPositionEstimator_

__all__ = ["FusedChain_", "FusedChain", "ESTIMATE_OUTPUTS"]

#: the fused system's estimate outputs, by the estimated measurement they replace
ESTIMATE_OUTPUTS = {"joint_angle": "joint_angle_estimate", "joint_velocity": "joint_velocity_estimate"}
_INTERNAL = ("joint_angle", "joint_velocity", "tendon_force_reference", "tendon_path_velocity")


@TemplateSystem.define("FusedChain_", scope=sys.modules[__name__], T_list=[float, AutoDiffXd])
def FusedChain_(T):
    """Estimator -> joint stage -> distribution -> tendon force law as one discrete system (module docstring).

    ``spec`` (a dict, built by :meth:`~awiwi_drake.control.chain.TendonChainController.fused_spec` or by
    :func:`~awiwi_drake.control.base.closed_loop` for a static law): ``estimator`` (the
    :class:`~awiwi_drake.hand.estimation.LinkStateEstimator`'s position estimator arguments ``coupling,
    motor_pulley_radius, offsets, period, iterations, step0, refine``), ``velocity_time_constant``, ``wrist``
    (bool), ``law`` (the last stage, a static law giving ``motor_torque``), and for a chain ``joint_law``,
    ``stiffness`` (the constant ``joint_stiffness_reference``), ``distribution`` (the
    :class:`TendonForceDistribution_` keyword arguments) or ``sharing`` (``(W, f_op, tau_op)``), ``path_coupling``
    (``P(q)`` for ``tendon_path_velocity``) and ``initial_forces``.

    Inputs: ``joint_angle_reference`` and the rig outputs the stages read (``motor_angle``, ``elongation``,
    [``wrist_tendon_offset``], ``tendon_force``, ...).  Outputs: ``motor_torque``, ``joint_angle_estimate``,
    ``joint_velocity_estimate`` and for a chain ``tendon_force_reference``, ``joint_torque_reference``,
    ``joint_stiffness_reference`` [, ``distribution_status``] (the composed chain's outputs).
    """

    class Impl(LeafSystem_[T]):
        def _construct(self, spec: dict, converter=None):
            LeafSystem_[T].__init__(self, converter)
            self.spec = spec
            est = spec["estimator"]
            given = spec.get("estimator_system")      # the float blocks themselves, reused on the float path
            self.estimator = given if (T is float and given is not None) else LinkPositionEstimator_[T](**est)
            n, m = est["coupling"].num_joints, est["coupling"].num_tendons
            self.period = float(est["period"])
            Tv = float(spec["velocity_time_constant"])
            a = self.period / Tv
            # the velocity filter's matrices as Drake's LinearSystem holds them (same arithmetic, same rounding)
            self._fa, self._fb, self._fc, self._fd = 1.0 - a, a, -1.0 / Tv, 1.0 / Tv
            self.law, self.joint_law = spec["law"], spec.get("joint_law")
            self.dist = None
            if spec.get("distribution") is not None:
                given = spec.get("distribution_system")
                self.dist = given if (T is float and given is not None) else TendonForceDistribution_[T](
                    **spec["distribution"])
            self.sharing = spec.get("sharing")
            self.path_coupling = spec.get("path_coupling")
            self.obs = None
            given = spec.get("observer_system")       # the sampled (9.2) observer block, its own methods
            if given is not None:
                self.obs = given if T is float else given.ToAutoDiffXd()
            names = {"joint_angle_reference": n, "motor_angle": m, "elongation": m}
            if spec.get("wrist"):
                names["wrist_tendon_offset"] = m
            if self.obs is not None:
                names["tendon_force"] = m
            for stage in (self.joint_law, self.law):
                if stage is not None:
                    names.update({k: v for k, v in stage.inputs.items() if k not in _INTERNAL})
            self._in = {nm: self.DeclareVectorInputPort(nm, int(sz)) for nm, sz in names.items()}
            self._xq = self.DeclareDiscreteState(n)
            self._xz = self.DeclareDiscreteState(n)
            chain = self.joint_law is not None
            K = np.asarray(spec["stiffness"], dtype=float) if chain else None
            self._K = K if (T is float or K is None) else np.array([AutoDiffXd(k) for k in K], dtype=object)
            if self.dist is not None:
                self._xf = self.DeclareDiscreteState(self.dist.initial_forces)
                self._xs = self.DeclareDiscreteState(len(self.dist.fingers))
            if self.obs is not None:
                self._xw = self.DeclareDiscreteState(self.obs.S.shape[1])
            self._xg = None
            if getattr(self.law, "initial_gain", None) is not None:   # held gains (the tendon SDRE, ch. 14)
                self._xg = self.DeclareDiscreteState(self.law.initial_gain)
                if self.law.update_period is not None:
                    self.DeclarePeriodicDiscreteUpdateEvent(self.law.update_period, 0.0, self._update_gain)
            self.DeclarePeriodicDiscreteUpdateEvent(self.period, 0.0, self._update)
            tickets = {p.ticket() for p in self._in.values()} | {self.xd_ticket()}
            self._cache = self.DeclareCacheEntry("fused chain at the sample", ValueProducer(
                allocate=lambda: AbstractValue.Make(None), calc=self._calc_sample), tickets)
            self._sample_output("motor_torque", self.law.output_size, "u")
            self._sample_output("joint_angle_estimate", n, "q")
            self._sample_output("joint_velocity_estimate", n, "v")
            if self._xg is not None:
                self.DeclareStateOutputPort(self.law.gain_name, self._xg)
            if chain:
                if self.dist is not None:
                    self.DeclareStateOutputPort("tendon_force_reference", self._xf)
                    self.DeclareStateOutputPort("distribution_status", self._xs)
                else:
                    self._sample_output("tendon_force_reference", m, "f_ref")
                self._sample_output("joint_torque_reference", self.joint_law.output_size, "tau")
                if self.obs is not None:
                    self._sample_output("friction_compensation", self.obs.S.shape[1], "comp")
                    if self.obs.levels is not None:
                        self._sample_output("friction_compensation_bound", self.obs.S.shape[1], "bound")
                self.DeclareVectorOutputPort("joint_stiffness_reference", K.size,
                                             lambda c, o: o.SetFromVector(self._K),
                                             prerequisites_of_calc={self.nothing_ticket()})
            self.set_name(spec.get("name", "fused_chain"))

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.spec, converter=converter)

        def _sample_output(self, name, size, key):
            """An output port reading ``key`` of the sample (:meth:`_calc_sample`)."""
            self.DeclareVectorOutputPort(name, int(size), lambda c, o: o.SetFromVector(self._sample(c)[key]),
                                         prerequisites_of_calc={self._cache.ticket()})

        def _sample(self, context) -> dict:
            return self._cache.Eval(context)

        def _calc_sample(self, context, value) -> None:
            """Everything the composed loop evaluates at the sample (module docstring), once."""
            meas = {nm: p.Eval(context) for nm, p in self._in.items()}
            xd = context.get_discrete_state()
            q = self.estimator.estimate(meas["motor_angle"], meas["elongation"], meas.get("wrist_tendon_offset"),
                                        xd.get_vector(self._xq).CopyToVector())
            z = xd.get_vector(self._xz).CopyToVector()
            v = self._fc * z + self._fd * q
            u = dict(meas, joint_angle=q, joint_velocity=v)
            out = dict(q=q, v=v, z=z, f=meas.get("tendon_force"))
            if self.joint_law is not None:
                if self.dist is not None:
                    u["tendon_force_reference"] = out["f_prev"] = xd.get_vector(self._xf).CopyToVector()
                tau = np.asarray(self.joint_law(u)).reshape(-1)
                if self.path_coupling is not None:     # P(q_k), once per period: the observer reuses it
                    out["P"] = np.asarray(self.path_coupling.P(q))
                    u["tendon_path_velocity"] = out["P"] @ v
                if self.obs is not None:            # ch. 9: the stage's torques plus -d_hat, bounded
                    out["w_hat"] = xd.get_vector(self._xw).CopyToVector()
                    B = self.obs.friction_bound(q, out["f"], out.get("P"))
                    out["comp"] = self.obs.compensation(out["w_hat"], v, B)
                    if B is not None:
                        out["bound"] = self.obs.scale * B
                    tau = tau + out["comp"]
                if self.sharing is not None:
                    W, f0, tau0 = self.sharing
                    u["tendon_force_reference"] = f0 + W @ (tau - tau0)
                out.update(tau=tau, f_ref=u["tendon_force_reference"])
            if self._xg is not None:
                u[self.law.gain_name] = xd.get_vector(self._xg).CopyToVector()
            out["u"] = np.asarray(self.law(u)).reshape(-1)
            value.set_value(out)

        def _update(self, context, discrete_state):
            s = self._sample(context)
            q = s["q"]
            self.estimator.note_limit(q)
            discrete_state.set_value(self._xq, q)
            discrete_state.set_value(self._xz, self._fa * s["z"] + self._fb * q)     # the states read at the sample
            if self.dist is not None:
                f_new, status = self.dist.step(s["tau"], self._K, s["f_prev"],
                                               q if self.dist.reads_joint_angle else None)
                discrete_state.set_value(self._xf, f_new)
                discrete_state.set_value(self._xs, status)
            if self.obs is not None:
                discrete_state.set_value(self._xw, self.obs.next_state(s["w_hat"], q, s["v"], s["f"], s.get("P")))

        def _update_gain(self, context, discrete_state):
            """The tendon SDRE's re-solve at the measured inputs (:meth:`TendonSdreLaw.gains_at`), as its own system."""
            k = self.law.gains_at({nm: np.array([scalar_value(v) for v in self._in[nm].Eval(context)])
                                   for nm in self.law.gain_inputs})
            discrete_state.set_value(self._xg, k if T is float else np.array([AutoDiffXd(v) for v in k], dtype=object))

        def initialize_state(self, context, joint_angles, joint_velocities=None) -> None:
            """Start the estimate and the velocity filter at ``joint_angles`` (a pose known after homing; None
            keeps them as they are, as the composed loop keeps its estimator's), the distribution at the design
            point's forces and the friction observer at ``joint_velocities`` (0 at rest) (``context``: this
            system's)."""
            if joint_angles is not None:
                q = np.asarray(joint_angles, dtype=float).reshape(-1)
                context.SetDiscreteState(self._xq, q)
                context.SetDiscreteState(self._xz, q)
            if self.obs is not None:
                v = (np.zeros(self.obs.S.shape[0]) if joint_velocities is None
                     else np.asarray(joint_velocities, float))
                context.SetDiscreteState(self._xw, self.obs.Sp @ v)
            f0 = self.spec.get("initial_forces")
            if self.dist is not None and f0 is not None:
                context.SetDiscreteState(self._xf, np.asarray(f0, dtype=float))

    return Impl


FusedChain = FusedChain_[None]
