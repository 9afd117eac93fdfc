"""Hand-written models against the framework at random states (as Drake's examples check a
hand-written pendulum against MultibodyPlant to 1e-8).

The model-discrepancy workflow integrates its own copies of the joint rig (``DiscrepancyModel_``,
written for batched replay, and the truth generator's ``HiddenEffectPlant_``); with the same
parameters and the catalog effects that the rig also has, their time derivatives must equal
those of the rig's Drake diagram (MultibodyPlant link, motor bank, spring bank, routing).
"""

import numpy as np
import pytest

from awiwi_drake.discrepancy.catalog import PARAM_INDEX, default_vector
from awiwi_drake.discrepancy.model import DiscrepancyModel, NominalParameters
from awiwi_drake.discrepancy.truth import HiddenEffectPlant_
from awiwi_drake.parameters import JointRigParams, MotorParams
from awiwi_drake.rigs import joint_rig


@pytest.mark.parametrize("friction", [False, True])
def test_discrepancy_model_equals_the_joint_rig_at_random_states(friction):
    motor = MotorParams(friction=friction, ripple=False, saturation=False, damping=1e-3)
    params = JointRigParams().replace(motor=motor, link_damping=2e-4)
    rig = joint_rig(params=params, backend="python")
    nominal = NominalParameters("joint", motor.inertia, motor.damping, motor.pulley_radius,
                                tuple(rig.spring.coefficients), params.link_inertia, params.link_damping,
                                params.link_pulley_radius)
    model = DiscrepancyModel(nominal)
    truth = HiddenEffectPlant_[float](nominal, {})          # the truth generator with nothing hidden
    P = default_vector()
    if friction:                                   # the catalog's (3.8) with the rig's Table 3.3 values
        for name, value in (("motor_coulomb", motor.coulomb_torque), ("motor_slope", motor.friction_slope),
                            ("motor_viscous", motor.viscous_friction)):
            P[PARAM_INDEX[name]] = value
    rig_ctx, model_ctx = rig.diagram.CreateDefaultContext(), model.CreateDefaultContext()
    model_ctx.get_mutable_numeric_parameter(0).SetFromVector(P)
    rig.diagram.GetInputPort("external_torque").FixValue(rig_ctx, [0.0])
    r, rq = motor.pulley_radius, params.link_pulley_radius
    rng = np.random.default_rng(11)
    for _ in range(8):
        q, qd = rng.uniform(-0.4, 0.4), rng.uniform(-3, 3)
        x = rng.uniform(-2e-4, 3e-3, 2)                     # elongations, some slack
        theta = np.array([(x[0] + rq * q) / r, (x[1] - rq * q) / r])
        omega, u = rng.uniform(-5, 5, 2), rng.uniform(-1, 1, 2)
        rig_ctx.SetContinuousState(np.r_[q, qd, theta, omega])
        rig.diagram.GetInputPort("motor_torque").FixValue(rig_ctx, u)
        xdot_rig = rig.diagram.EvalTimeDerivatives(rig_ctx).CopyToVector()
        model_ctx.SetContinuousState(np.r_[theta, omega, q, qd, 0.0, 0.0])
        model.get_input_port(0).FixValue(model_ctx, u)
        xdot = model.EvalTimeDerivatives(model_ctx).CopyToVector()
        # model order [theta, omega, q, q', z] -> rig order [q, q', theta, omega]
        mapped = np.r_[xdot[4:6], xdot[0:4]]
        np.testing.assert_allclose(mapped, xdot_rig, rtol=1e-9, atol=1e-9 * np.max(np.abs(xdot_rig)))
        if not friction:          # the truth plant's friction is Stribeck (deliberately not (3.8))
            truth_ctx = truth.CreateDefaultContext()
            truth_ctx.SetContinuousState(np.r_[theta, omega, q, qd, 0.0, 0.0])
            truth.get_input_port(0).FixValue(truth_ctx, u)
            xdot = truth.EvalTimeDerivatives(truth_ctx).CopyToVector()
            np.testing.assert_allclose(np.r_[xdot[4:6], xdot[0:4]], xdot_rig, rtol=1e-9,
                                       atol=1e-9 * np.max(np.abs(xdot_rig)))
