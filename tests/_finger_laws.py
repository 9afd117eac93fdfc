"""The ideal finger/hand drive from the laws apart (not a test module): the independent reference the
compiled plant is checked against at random states."""

import numpy as np

from awiwi_drake.components.motor import motor_acceleration


def ideal_drive_derivatives(rig, q, v, theta, omega, u):
    """State derivative ``[qdot, vdot, thetadot, omegadot]`` of a finger/hand rig without hysteresis and guide
    friction: the routing's elongations ``x = r_m theta + h(q) - h(0) + x0``, each tendon's own spring law, the
    standalone MultibodyPlant (``rig.plant``, with its joint damping) under ``-P(q)^T f``, the motors' (3.5)
    with load ``r_m f``."""
    mp = rig.params.motor
    x = mp.pulley_radius * theta + rig.coupling.h(q) - rig.coupling.h(np.zeros_like(q)) + rig.offsets
    f = rig.spring_laws.force(x)
    ctx = rig.plant.CreateDefaultContext()
    rig.plant.SetPositionsAndVelocities(ctx, np.concatenate([q, v]))
    rig.plant.get_applied_generalized_force_input_port().FixValue(ctx, -np.asarray(rig.coupling.P(q)).T @ f)
    plant_dot = rig.plant.EvalTimeDerivatives(ctx).CopyToVector()
    return np.concatenate([plant_dot, omega, motor_acceleration(theta, omega, u, mp.pulley_radius * f, mp)])


def compiled(rig):
    """``rig`` with its plant on the compiled kernels from the first call (a fresh finger / hand system takes the
    generic path for its first ``parameters.hand.COMPILE_AFTER_CALLS`` float calls): for the tests that check the
    kernels against the laws."""
    rig.diagram.GetSubsystemByName("hand_dynamics").kernels()
    return rig
