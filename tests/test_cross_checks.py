"""Hand-written models against the laws written out apart at random states (as Drake's examples check a
hand-written pendulum against MultibodyPlant to 1e-8).

The model-discrepancy workflow integrates batched copies of the joint rig (``DiscrepancyModel_``, generated
from the rig's drive law with the catalog effects as switches, and compiled) and the truth generator's
hand-written ``HiddenEffectPlant_``; with the same parameters and the catalog effects that the rig also
has, their time derivatives must equal the joint rig's laws written out (spring law, (3.5), the link's
``I qdd = tau - d qd + tau_ext``: ``_joint_rig_check.rig_law_derivatives``), and so must the rig's diagram.
"""

import numpy as np
import pytest

from _joint_rig_check import assert_models_match_joint_rig
from awiwi_drake.discrepancy.catalog import PARAM_INDEX, default_vector
from awiwi_drake.discrepancy.model import DiscrepancyModel, NominalParameters
from awiwi_drake.discrepancy.truth import HiddenEffectPlant_
from awiwi_drake.parameters import JointRigParams, MotorParams
from awiwi_drake.rigs import joint_rig


@pytest.mark.parametrize("friction", [False, True])
def test_discrepancy_model_equals_the_joint_rig_at_random_states(friction):
    motor = MotorParams(friction=friction, ripple=False, saturation=False, damping=1e-3)
    params = JointRigParams().replace(motor=motor, link_damping=2e-4)
    rig = joint_rig(params=params)
    nominal = NominalParameters("joint-rig", motor.inertia, motor.damping, motor.pulley_radius,
                                tuple(rig.spring.coefficients), params.link_inertia, params.link_damping,
                                params.link_pulley_radius)
    model = DiscrepancyModel(nominal)
    truth = HiddenEffectPlant_[float](nominal, {})          # the truth generator with nothing hidden
    P = default_vector()
    if friction:                                   # the catalog's (3.8) with the rig's Table 3.3 values
        for name, value in (("motor_coulomb", motor.coulomb_torque), ("motor_slope", motor.friction_slope),
                            ("motor_viscous", motor.viscous_friction)):
            P[PARAM_INDEX[name]] = value
    model_ctx = model.CreateDefaultContext()
    model_ctx.get_mutable_numeric_parameter(0).SetFromVector(P)
    models = [(model, model_ctx)]
    if not friction:          # the truth plant's friction is Stribeck (deliberately not (3.8))
        models.append((truth, truth.CreateDefaultContext()))
    x = assert_models_match_joint_rig(models, rig, motor_pulley_radius=motor.pulley_radius,
                                      link_pulley_radius=params.link_pulley_radius, seed=11, samples=8,
                                      min_elongation=-2e-4)
    assert np.any(x < 0) and np.any(x > 0)          # both branches of the spring law: slack and taut tendons
