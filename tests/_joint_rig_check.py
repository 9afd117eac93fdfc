"""One check shared by the cross-check tests: a discrepancy replay model (state ``[q, q', theta, omega, z]``)
has the joint rig diagram's time derivatives (state ``[q, q', theta, omega]``) at random states."""
import numpy as np


def assert_models_match_joint_rig(models, rig, *, motor_pulley_radius, link_pulley_radius, seed, samples,
                                  min_elongation, rtol=1e-9):
    """``models`` is a list of ``(system, context)`` pairs whose parameters the caller has set. The states
    are drawn with elongations from ``min_elongation`` (negative: some tendons slack) to 3 mm.  Returns the drawn
    elongations (samples x 2), so that a caller can assert which branches of the laws the samples reached."""
    rig_ctx = rig.diagram.CreateDefaultContext()
    rig.diagram.GetInputPort("external_torque").FixValue(rig_ctx, [0.0])
    r, rq = motor_pulley_radius, link_pulley_radius
    rng = np.random.default_rng(seed)
    drawn = []
    for _ in range(samples):
        q, qd = rng.uniform(-0.4, 0.4), rng.uniform(-3, 3)
        x = rng.uniform(min_elongation, 3e-3, 2)
        drawn.append(x)
        theta = np.array([(x[0] + rq * q) / r, (x[1] - rq * q) / r])
        omega, u = rng.uniform(-5, 5, 2), rng.uniform(-1, 1, 2)
        rig_ctx.SetContinuousState(np.r_[q, qd, theta, omega])
        rig.diagram.GetInputPort("motor_torque").FixValue(rig_ctx, u)
        xdot_rig = rig.diagram.EvalTimeDerivatives(rig_ctx).CopyToVector()
        for system, ctx in models:
            ctx.SetContinuousState(np.r_[q, qd, theta, omega, 0.0, 0.0])   # the rig's order, then z
            system.get_input_port(0).FixValue(ctx, u)
            xdot = system.EvalTimeDerivatives(ctx).CopyToVector()
            np.testing.assert_allclose(xdot[:6], xdot_rig, rtol=rtol,
                                       atol=rtol * np.max(np.abs(xdot_rig)),
                                       err_msg=f"{system.get_name()} vs {rig.name} at q={q:.3g}, x={x}")
    return np.array(drawn)
