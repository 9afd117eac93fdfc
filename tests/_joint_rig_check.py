"""The single-joint rigs' dynamics from the laws apart (:func:`rig_law_derivatives`), and one check shared by
the cross-check tests: a discrepancy replay model (state ``[q, q', theta, omega, z]``) has the joint rig's time
derivatives (state ``[q, q', theta, omega]``) at random states."""
import numpy as np

from awiwi_drake.components.motor import motor_acceleration


def rig_law_derivatives(rig, x, u, e=None):
    """``xdot`` of a tendon rig, flexible joint or joint rig (no hysteresis) written out from the law functions,
    independently of the rig's construction: the spring law ``rig.spring``, (3.5) for the motors
    (:func:`motor_acceleration` with load ``r_m f``), ``I qdd = tau - d qd + tau_ext`` for the link."""
    p = rig.params
    x, u = np.asarray(x, float), np.asarray(u, float)
    if rig.name == "tendon-rig":                   # x = r_m theta, far end fixed
        theta, omega = x[:1], x[1:2]
        f = rig.spring.force(p.motor.pulley_radius * theta)
        return np.concatenate([omega, motor_acceleration(theta, omega, u, p.motor.pulley_radius * f, p.motor)])
    q, qd = x[0], x[1]
    if rig.name == "flexible-joint":               # (12.8): tau_s = phi(theta - q)
        theta, omega = x[2], x[3]
        tau_s = float(np.ravel(rig.spring.force(np.array([theta - q])))[0])
        qdd = (-p.link_damping * qd + tau_s + e[0]) / p.link_inertia
        return np.array([qd, qdd, omega, (u[0] - p.motor_damping * omega - tau_s) / p.motor_inertia])
    r, rq = p.motor.pulley_radius, p.link_pulley_radius   # joint rig: x1 = r th1 - rq q, x2 = r th2 + rq q
    theta, omega = x[2:4], x[4:6]
    f = rig.spring.force(np.array([r * theta[0] - rq * q, r * theta[1] + rq * q]))
    qdd = (rq * (f[0] - f[1]) - p.link_damping * qd + e[0]) / p.link_inertia
    return np.concatenate([[qd, qdd], omega, motor_acceleration(theta, omega, u, r * f, p.motor)])


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
        xdot_rig = rig_law_derivatives(rig, np.r_[q, qd, theta, omega], u, [0.0])
        np.testing.assert_allclose(rig.diagram.EvalTimeDerivatives(rig_ctx).CopyToVector(), xdot_rig, rtol=rtol,
                                   atol=rtol * np.max(np.abs(xdot_rig)))
        for system, ctx in models:
            ctx.SetContinuousState(np.r_[q, qd, theta, omega, 0.0, 0.0])   # the rig's order, then z
            system.get_input_port(0).FixValue(ctx, u)
            xdot = system.EvalTimeDerivatives(ctx).CopyToVector()
            np.testing.assert_allclose(xdot[:6], xdot_rig, rtol=rtol,
                                       atol=rtol * np.max(np.abs(xdot_rig)),
                                       err_msg=f"{system.get_name()} vs {rig.name} at q={q:.3g}, x={x}")
    return np.array(drawn)
