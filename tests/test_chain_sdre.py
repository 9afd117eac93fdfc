"""The ch. 14 tendon SDRE as the chain's per-tendon force law (``HandChainParams.tendon_law = "sdre"``): the closed-form
per-tendon Riccati gains against Drake's LQR, the bank against the tendon rig's own SDRE, the gain following the
spring's slope, the tendon rig's printed (14.9) SDRE as the same law, the system's scalar conversion and the index finger closed through it at 3 kHz."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.autodiffutils import AutoDiffXd, InitializeAutoDiff, ExtractGradient
from pydrake.systems.controllers import LinearQuadraticRegulator

from _fd import fd_jacobian
from awiwi_drake.analysis import simulate
from awiwi_drake.components import motor_friction_torque
from awiwi_drake.control import closed_loop, get_entry, make_controller
from awiwi_drake.control.sdre import (SDRE_GAIN, RigJacobian, TendonSdreController, TendonSdreController_,
                                      TendonSdreLaw, tendon_sdre_controller, tendon_sdre_gains)
from awiwi_drake.components.spring import tendon_spring
from awiwi_drake.control.tendon_force import ForceMap, force_map
from awiwi_drake.hand.diagrams import finger_diagram
from awiwi_drake.parameters import MotorParams, TendonRigParams
from awiwi_drake.parameters.hand import FingerRigParams
from awiwi_drake.parameters.control import SdreTendonParams
from awiwi_drake.parameters.hand_control import HandChainParams
from awiwi_drake.rigs import tendon_rig


def test_closed_form_tendon_riccati_equals_drakes_lqr_at_random_tendon_states():
    """(14.9) with a viscous slope, ``A = [[0, 1], [-s/B, -d/B]]``, ``B_u = [0, 1/B]``: the closed form against Drake's
    ``LinearQuadraticRegulator`` on 40 random tendon states (slope, friction slope, inertia, Q, R), all at once (the
    bank's broadcasting), to 1e-9; and the closed loop is the docstring's ``s^2 + 2 zeta w s + w^2`` with
    ``w^4 = a^2 + c q_theta``."""
    rng = np.random.default_rng(14)
    n = 40
    s, d = rng.uniform(0.0, 3.0, n), rng.uniform(0.0, 6.0, n)
    for k in range(n):
        B, q, r = rng.uniform(1e-4, 5e-3), (10 ** rng.uniform(-3, 1), rng.uniform(0, 1e-3)), 10 ** rng.uniform(-7, -3)
        kt, kw = tendon_sdre_gains(s, B, q, r, damping=d)          # the whole bank, one call
        A = np.array([[0.0, 1.0], [-s[k] / B, -d[k] / B]])
        Bu = np.array([[0.0], [1.0 / B]])
        K, _ = LinearQuadraticRegulator(A, Bu, np.diag(q), np.array([[r]]))
        np.testing.assert_allclose([kt[k], kw[k]], K[0], rtol=1e-9)
        a, c = s[k] / B, 1.0 / (B * B * r)
        poly = np.poly(A - Bu @ K)                                  # s^2 + p1 s + p0
        np.testing.assert_allclose(poly[2], np.sqrt(a * a + c * q[0]), rtol=1e-9)
    with pytest.raises(ValueError, match="q_theta > 0"):
        tendon_sdre_gains(1.0, 2e-3, (0.0, 0.0), 1e-6)


def test_printed_tendon_sdre_is_one_law_equal_to_drakes_lqr_on_14_9_and_the_jacobian_form_adds_the_friction_slope():
    """One (14.9) law for the bank and the tendon rig: the bank's gain at 30 N and the registered ``tendon-sdre``'s
    printed form (its design gain and its re-solve at the measured motor angle: 5, 40, 100 N on the spring and slack,
    where the force is 0) each equal Drake's ``LinearQuadraticRegulator`` on (14.9) built here,
    ``A = [[0, 1], [-r_m alpha / B, 0]]``, ``B_u = [0, 1/B]``, ``alpha`` the rig's force map's slope at that force
    (Table 14.1's Q, R).  The rig's default form (Drake autodiff of the rig: the (3.8) friction slope at rest enters
    ``A``) equals the closed form given that slope as ``damping``, computed from the friction law itself."""
    rig = tendon_rig()
    fmap = force_map(rig)
    p = SdreTendonParams()
    motor = rig.params.motor
    B, r_m = motor.inertia, motor.pulley_radius

    def drake_lqr(f):
        A = np.array([[0.0, 1.0], [-r_m * float(fmap.alpha_of_force(f)) / B, 0.0]])
        return LinearQuadraticRegulator(A, np.array([[0.0], [1.0 / B]]), np.diag(p.q_diag), np.array([[p.r]]))[0][0]
    law = TendonSdreLaw([fmap], motor, q_diag=p.q_diag, r=p.r, design_forces=[30.0], update_period=None)
    np.testing.assert_allclose(law.initial_gain, drake_lqr(30.0), rtol=1e-9)
    printed = tendon_sdre_controller(rig, p.replace(factorisation="printed"), design_force=30.0, fmap=fmap)
    np.testing.assert_allclose(printed.law.initial_gain, drake_lqr(30.0), rtol=1e-9)
    for f in (5.0, 40.0, 100.0):
        th = float(fmap.theta_of_force(f))
        np.testing.assert_allclose(printed.law.gains_at({"motor_angle": np.array([th])}), drake_lqr(f), rtol=1e-9)
    slack = printed.law.gains_at({"motor_angle": np.array([fmap.slack_angle - 0.1])})
    np.testing.assert_allclose(slack, drake_lqr(0.0), rtol=1e-9)
    w = InitializeAutoDiff(np.zeros(1))[0, 0]
    slope = -motor_friction_torque(w, motor).derivatives()[0]       # d(friction)/d(omega) at rest [Nm s/rad]
    assert slope > 1.0                                              # (3.8) at rest: ~5.6 Nm s/rad
    jac = tendon_sdre_controller(rig, p, design_force=30.0, fmap=fmap)
    kt, kw = tendon_sdre_gains(r_m * fmap.alpha_of_force(30.0), B, p.q_diag, p.r, damping=slope)
    np.testing.assert_allclose([kt, kw], jac.law.initial_gain, rtol=1e-9)
    # the friction slope moves K_omega (6.0 vs 10.2)
    assert abs(jac.law.initial_gain[1] - printed.law.initial_gain[1]) > 1.0


def test_the_gain_follows_the_state_through_the_springs_slope():
    """Two tendons of a bank at two forces on the spring curve (5 N and 80 N, table rows: no interpolation) get the
    LQR gains of the rig's linearisations there (Drake autodiff of the frictionless tendon rig at the motor angle
    holding each force); the two differ (the spring's slope differs 3.6x), by far more than the agreement.  The
    chain's derived weights give each closed loop the (10.2) law's bandwidth and LQR's own damping."""
    rig = tendon_rig(params=TendonRigParams(motor=MotorParams(friction=False, ripple=False, damping=0.0)))
    fmap = force_map(rig)
    rows = [int(np.searchsorted(fmap.force, f)) for f in (5.0, 80.0)]
    forces = fmap.force[rows]
    assert fmap.alpha[rows[1]] > 3 * fmap.alpha[rows[0]]
    motor, hc = rig.params.motor, HandChainParams()
    q = hc.tendon_sdre_weights(motor.inertia)
    law = TendonSdreLaw([fmap, fmap], motor, q_diag=q, r=hc.sdre_input_weight, design_forces=forces,
                        update_period=1.0 / hc.sdre_update_rate)
    k = law.gains(forces).reshape(2, 2).T                             # rows: tendons, columns: K_theta, K_omega
    jac = RigJacobian(rig)
    for i, row in enumerate(rows):
        A, B = jac(np.array([fmap.theta[row], 0.0]), np.array([motor.pulley_radius * forces[i]]))
        K, _ = LinearQuadraticRegulator(A, B, np.diag(q), np.array([[hc.sdre_input_weight]]))
        np.testing.assert_allclose(k[i], K[0], rtol=1e-9)
        # the derived weights give the (10.2) loop's bandwidth w_f: w_n^4 = w_f^4 + a^2, so 0 <= w_n / w_f - 1 <=
        # a^2 / (4 w_f^4) (a = -A[1, 0], the spring's share), and LQR's damping with q_omega = 0
        wf, a = hc.force_bandwidth, -A[1, 0]
        wn = np.sqrt(abs(np.prod(np.linalg.eigvals(A - B @ K))))
        assert 0.0 <= wn / wf - 1.0 <= a * a / (4 * wf ** 4) + 1e-12
        assert -np.trace(A - B @ K) / (2 * wn) == pytest.approx(np.sqrt(2 * (wn * wn - a)) / (2 * wn), rel=1e-9)
    assert np.all(np.abs(k[1] - k[0]) > 1e-4 * np.abs(k[0]))          # 1e5 x the agreement's 1e-9


def test_tendon_sdre_system_converts_holds_and_refreshes_its_gain_and_names_a_bad_reference():
    """``TendonSdreController_``: the compiled float path equals the law as written (the measured force or the motor
    angle as the state), AutoDiffXd conversion (values equal, the derivative by the measured forces equals
    finite differences of the float system), the periodic update re-solves the gain at the measured forces, and a
    reference outside a tendon's table names that tendon.  A bank of 8 tendons on two spring laws (the hand's lever
    mechanism with and without the tendon's elasticity in series), alternating."""
    p = FingerRigParams.for_finger("index")
    r_m = p.motor.pulley_radius
    two = [ForceMap.from_spring(tendon_spring(sp), r_m) for sp in (p.spring, p.spring.replace(include_tendon=False))]
    m = 8
    maps = [two[i % 2] for i in range(m)]
    hc = HandChainParams()
    law = TendonSdreLaw(maps, p.motor, q_diag=hc.tendon_sdre_weights(p.motor.inertia), r=hc.sdre_input_weight,
                        design_forces=np.full(m, 20.0), update_period=1.0 / hc.sdre_update_rate,
                        ripple_scale=1.0, path_velocity=True)
    sys_ = TendonSdreController(law)
    assert TendonSdreController_[AutoDiffXd] is not None and sys_.ToAutoDiffXd() is not None
    rng = np.random.default_rng(3)
    vals = {"tendon_force_reference": rng.uniform(5, 40, m), "tendon_force": rng.uniform(5, 40, m),
            "motor_velocity": rng.uniform(-2, 2, m), "motor_angle": rng.uniform(-1, 1, m),
            "tendon_path_velocity": rng.uniform(-0.01, 0.01, m)}
    # the float bank's compiled path equals the law as written (at the initial and at re-solved gains)
    for k in (law.initial_gain, law.gains(vals["tendon_force"])):
        u = dict(vals, **{SDRE_GAIN: k})
        np.testing.assert_allclose(law(u), law.evaluate(u), rtol=0, atol=1e-12 * np.abs(law.evaluate(u)).max())
    assert law.__dict__.get("_kernel") is not None
    # the same bank with the motor angle as each tendon's state (the tendon rig's form): compiled = as written too
    by_angle = TendonSdreLaw(maps, p.motor, q_diag=law.q_diag, r=law.r, design_forces=np.full(m, 20.0),
                             update_period=None, ripple_scale=1.0, path_velocity=True, state="motor_angle")
    u = {nm: v for nm, v in vals.items() if nm != "tendon_force"}
    u[SDRE_GAIN] = by_angle.initial_gain
    np.testing.assert_allclose(by_angle(u), by_angle.evaluate(u), rtol=0,
                               atol=1e-12 * np.abs(by_angle.evaluate(u)).max())
    assert by_angle.__dict__.get("_kernel") is not None and "tendon_force" not in by_angle.inputs
    ctx = sys_.CreateDefaultContext()
    for nm, v in vals.items():
        sys_.GetInputPort(nm).FixValue(ctx, v)
    u0 = sys_.GetOutputPort("motor_torque").Eval(ctx).copy()
    ad = sys_.ToAutoDiffXd()
    actx = ad.CreateDefaultContext()
    for nm, v in vals.items():
        ad.GetInputPort(nm).FixValue(actx, InitializeAutoDiff(v).reshape(-1) if nm == "tendon_force"
                                     else np.array([AutoDiffXd(x) for x in v], dtype=object))
    ua = ad.GetOutputPort("motor_torque").Eval(actx)
    np.testing.assert_allclose([x.value() for x in ua], u0, rtol=0, atol=1e-12 * np.abs(u0).max())

    def command(f):
        sys_.GetInputPort("tendon_force").FixValue(ctx, f)
        return sys_.GetOutputPort("motor_torque").Eval(ctx).copy()
    G = ExtractGradient(ua)
    fd = fd_jacobian(command, vals["tendon_force"], h=1e-6)
    assert np.abs(np.diag(G)).min() > 0                               # the force error moves every command
    np.testing.assert_allclose(G, fd, rtol=1e-5, atol=1e-5 * np.abs(fd).max())
    sys_.GetInputPort("tendon_force").FixValue(ctx, vals["tendon_force"])
    np.testing.assert_array_equal(sys_.GetOutputPort(SDRE_GAIN).Eval(ctx), law.initial_gain)
    new = sys_.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector().CopyToVector()
    np.testing.assert_array_equal(new, law.gains(vals["tendon_force"]))
    assert np.abs(new - law.initial_gain).max() > 0
    bad = vals["tendon_force_reference"].copy()
    bad[5] = -1.0
    sys_.GetInputPort("tendon_force_reference").FixValue(ctx, bad)
    with pytest.raises(ValueError, match=r"tendon_force_reference\[5\] = -1.0"):
        sys_.GetOutputPort("motor_torque").Eval(ctx)


def test_index_finger_chain_with_the_sdre_force_law_steps_a_joint_and_holds_the_others():
    """Cascaded on the index (default physics, estimator, 3 kHz, fused) with ``tendon_law="sdre"``: one
    ``TendonSdreController_`` for the 8 tendons in the composed chain; a 0.2 rad MCP step settles into compare's 2 %
    band within the window its design derives (0.02 s + 5 x the MCP's own slowest designed mode), the other DoF
    stay in that band, the tendons stay taut and below their table, and the held gains move with the forces; the
    fused chain equals the composed blocks."""
    rig = finger_diagram(finger="index")
    ctrl = make_controller("cascaded", rig, chain_params=HandChainParams(tendon_law="sdre"))
    stage = ctrl.GetSubsystemByName("force_stage").GetSubsystemByName("tendon_force_control")
    assert isinstance(stage, TendonSdreController_[float]) and stage.law.output_size == 8
    loop = closed_loop(rig, ctrl, **get_entry("cascaded", rig).loop_options)
    assert loop.fused is not None and loop.rate_hz == 3000.0
    with pytest.raises(ValueError, match="the two-time-scale chain's tendon level is its own motor-position loop"):
        make_controller("two-time-scale", rig, chain_params=HandChainParams(tendon_law="sdre"))
    design = ctrl.design.joint_design
    S = ctrl.design.selection
    mcp = 1
    window = 0.02 + 5.0 * design.tracking_time_constants()[mcp]
    op = rig.operating_point()
    q_ref = op.joint_angle + 0.2 * S[:, mcp]
    res = simulate(loop.diagram, loop.create_context(op, references={"joint_angle_reference": q_ref}), window,
                   log=("joint_angle", "tendon_force", f"controller_{SDRE_GAIN}"))
    e = np.linalg.pinv(S) @ (res["joint_angle"][-1] - q_ref)
    assert np.all(np.abs(e) < 0.02 * 0.2), e
    f = res["tendon_force"]
    assert f.min() > 0.0 and f.max() < min(fm.max_force for fm in stage.law.fmaps)
    K = res[f"controller_{SDRE_GAIN}"]
    assert np.abs(K[-1] - stage.law.initial_gain).max() > 0.0
    # the fused chain (its own gain refresh) equals the composed blocks over two 200 Hz refreshes, to round-off
    rig2 = finger_diagram(finger="index")
    composed = closed_loop(rig2, ctrl, fused=False, **get_entry("cascaded", rig2).loop_options)
    assert composed.fused is None
    logs = ("motor_torque", "tendon_force", "joint_angle_estimate", f"controller_{SDRE_GAIN}")
    a, b = (simulate(lp.diagram, lp.create_context(op, references={"joint_angle_reference": q_ref}), 0.011, log=logs)
            for lp in (loop, composed))
    np.testing.assert_array_equal(a.t, b.t)
    for nm in logs:
        np.testing.assert_allclose(b[nm], a[nm], rtol=0, atol=1e-12 * max(1.0, np.abs(a[nm]).max()), err_msg=nm)
    assert len({tuple(k) for k in a[f"controller_{SDRE_GAIN}"]}) >= 3      # refreshed at 0.005 and 0.010 s
