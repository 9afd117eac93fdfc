"""Optimal backstepping gains (ch. 16): K_bs(Omega) derived from the controller, ARE, gain search."""

import concurrent.futures as cf

import numpy as np
import pytest

from awiwi_drake.control.backstepping import ImpedanceBackstepping, joint_model
from awiwi_drake.control.optimal_gains import (
    backstepping_feedback, backstepping_feedback_batch, evaluate_samples, monte_carlo_gains, optimal_feedback,
    optimize_gains, system_feedback)
from awiwi_drake.reproductions.ch16_optimal_backstepping import printed_model_feedback, table_16_1_rig
from awiwi_drake.parameters.backstepping import ImpedanceBacksteppingGains, OptimalGainsCase
from _fd import fd_jacobian


def _torque_coordinates(k: float) -> np.ndarray:
    """``T`` with ``[q, qd, tau, taud] = T [q, qd, theta, thetad]``, ``tau = k (theta - q)`` (Table 16.1's
    coordinates of the flexible joint, written out)."""
    return np.array([[1, 0, 0, 0], [0, 1, 0, 0], [-k, 0, k, 0], [0, -k, 0, k]], dtype=float)


def _k_bs_closed_form(M, Bm, k, Kp, Kd, K3, K4):
    """(16.3) derived by hand from the design of section 15.3 (no damping, r = 0, no external torque).

    tau coordinates x = [q, qd, tau, taud], M qdd = tau, taudd = k (u - tau)/Bm - k tau/M.
    alpha = -Kp q - Kd qd, z3 = tau - alpha, beta = alpha' - K3 z3 - qd, z4 = taud - beta,
    taudd := beta' - z3 - K4 z4  =>  u = b (beta' - z3 - K4 z4) + tau (1 + Bm/M), b = Bm/k;
    u = -K x collects to the four entries below.
    """
    b = Bm / k
    return np.array([
        b * Kp * (1 + K3 * K4),
        b * (K3 * Kp + Kd + K4 * (Kp + K3 * Kd + 1)),
        b / M * (Kp + K3 * Kd + 1 + K4 * Kd) + b * (1 + K3 * K4) - 1 - Bm / M,
        b * (Kd / M + K3 + K4)])


def test_state_feedback_equals_an_independent_derivation_of_16_3():
    """All four entries of K_bs (AutoDiff of the law, and through the TemplateSystem) equal the
    hand derivation for random gains; the printed constants of entries 1, 2, 4 (0.0033 = Bm/k,
    4600 = Bm/(k M)) agree, entry 3's constant does not: printed 7400 = Bm/(kM) + Bm/M, the
    derivation gives Bm/(kM) - Bm/M - 1 + Bm/k = 1812.6 (a sign error in the thesis)."""
    rig = table_16_1_rig()
    c = OptimalGainsCase()
    model = joint_model(rig)
    Tinv = np.linalg.inv(_torque_coordinates(c.stiffness))
    rng = np.random.default_rng(5)
    for i in range(5):
        Kp, Kd, K3, K4 = np.exp(rng.uniform(np.log([1e-2, 1e-4, 1.0, 1.0]), np.log([2.0, 0.1, 200.0, 500.0])))
        g = ImpedanceBacksteppingGains(stiffness=Kp, damping=Kd, k3=K3, k4=K4)
        K_law = backstepping_feedback(model, g).ravel()
        if i == 0:
            K_sys = system_feedback(ImpedanceBackstepping(model, g, external_torque="none"), np.zeros(4)).ravel()
            np.testing.assert_allclose(K_sys, K_law, rtol=1e-12)
        expected = _k_bs_closed_form(c.link_inertia, c.motor_inertia, c.stiffness, Kp, Kd, K3, K4)
        np.testing.assert_allclose(K_law @ Tinv, expected, rtol=1e-9)
    b, b_over_M = c.motor_inertia / c.stiffness, c.motor_inertia / (c.stiffness * c.link_inertia)
    assert round(b, 4) == 0.0033 and round(b_over_M, -2) == 4600          # printed coefficients
    constant = _k_bs_closed_form(c.link_inertia, c.motor_inertia, c.stiffness, 0, 0, 0, 0)[2]
    assert constant == pytest.approx(1812.6, abs=0.1)
    assert b_over_M + c.motor_inertia / c.link_inertia == pytest.approx(7400, rel=5e-3)   # the printed 7400


def test_batched_feedback_equals_the_closed_form_and_the_controller_system_sample_by_sample():
    """Algorithm 3's batch (one AutoDiff evaluation of the law for many Omega, run_sweep(batch=...)):
    every sample equals the hand derivation (16.3) (flexible joint) and, for the two-motor joint rig,
    the controller *system* converted to AutoDiffXd with that sample's gains."""
    from awiwi_drake.control.optimal_gains import gain_distance, torque_state_map
    from awiwi_drake.rigs import joint_rig
    rng = np.random.default_rng(9)
    c = OptimalGainsCase()
    model = joint_model(table_16_1_rig())
    omegas = np.exp(rng.uniform(np.log([1e-2, 1e-4, 1.0, 1.0]), np.log([2.0, 0.1, 200.0, 500.0]), size=(64, 4)))
    K = backstepping_feedback_batch(model, omegas)
    assert K.shape == (64, 1, 4)
    Tinv = np.linalg.inv(_torque_coordinates(c.stiffness))
    for s_, om in enumerate(omegas):
        expected = _k_bs_closed_form(c.link_inertia, c.motor_inertia, c.stiffness, *om)
        np.testing.assert_allclose(K[s_, 0] @ Tinv, expected, rtol=1e-9)
    target = expected * 1.1
    d = evaluate_samples([dict(zip(("stiffness", "damping", "k3", "k4"), om)) for om in omegas], model=model,
                         T_inv=Tinv, target=target)
    assert d[-1] == pytest.approx(2 * 0.1 / 1.1, rel=1e-9)     # 4 entries, each 0.1/1.1 off (relative to target)
    rig = joint_rig()
    jm, op = joint_model(rig), rig.operating_point(pretension=25.0)
    Kj = backstepping_feedback_batch(jm, omegas[:3], op.state)
    assert Kj.shape == (3, 2, 6)
    for s_, om in enumerate(omegas[:3]):
        g = ImpedanceBacksteppingGains(stiffness=om[0], damping=om[1], k3=om[2], k4=om[3])
        K_sys = system_feedback(ImpedanceBackstepping(jm, g, external_torque="none"), op.state)
        np.testing.assert_allclose(Kj[s_], K_sys, rtol=1e-12, atol=1e-12 * np.max(np.abs(K_sys)))
    Tj = np.linalg.inv(torque_state_map(jm, op.state))
    dj = evaluate_samples([dict(zip(("stiffness", "damping", "k3", "k4"), om)) for om in omegas[:3]], model=jm,
                          T_inv=Tj, target=Kj[0] @ Tj * 2.0, state0=op.state)
    assert dj[0] == pytest.approx(gain_distance(Kj[0] @ Tj, Kj[0] @ Tj * 2.0), rel=1e-12) and dj[0] > 0


def test_printed_kdes_of_table_16_1_destabilises_the_printed_model():
    """Table 16.1's Kdes with its own (A, B): unstable under u = -K x and under u = +K x."""
    c = OptimalGainsCase()
    M, Bm, k = c.link_inertia, c.motor_inertia, c.stiffness
    A = np.array([[0, 1, 0, 0], [0, 0, 1 / M, 0], [0, 0, 0, 1], [0, 0, 0, 0.0]])
    B = np.array([[0], [0], [0], [k / Bm]])
    K = np.array([c.printed_kdes])
    for sign in (-1.0, 1.0):
        assert np.max(np.linalg.eigvals(A + sign * B @ K).real) > 500.0   # +1175 / +586 1/s


def test_lqr_from_framework_and_the_printed_table():
    rig = table_16_1_rig()
    K_tau, K_rig = optimal_feedback(rig)
    # scalar closed form of the ARE's position gain for an integrator chain: sqrt(Q11/R)
    assert K_tau[0] == pytest.approx(np.sqrt(100.0 / 0.1), rel=1e-6)
    printed = np.array(OptimalGainsCase().printed_kdes)
    ours = printed_model_feedback()
    assert ours[0] == pytest.approx(-np.sqrt(1000.0), rel=1e-6)
    assert not np.allclose(ours, printed, rtol=0.1)        # Table 16.1's Kdes does not follow from its A, B, Q, R


def test_table_16_1_target_is_below_the_structural_floor():
    """Every Omega > 0 gives a tau-gain above the LQR's: the R = 0.1 target is unreachable."""
    rig = table_16_1_rig()
    c = OptimalGainsCase()
    model = joint_model(rig)
    target, _ = optimal_feedback(rig, c)
    Tinv = np.linalg.inv(_torque_coordinates(c.stiffness))
    rng = np.random.default_rng(0)
    for _ in range(20):
        om = np.exp(rng.uniform(np.log(c.gain_low), np.log(c.gain_high)))
        g = ImpedanceBacksteppingGains(stiffness=om[0], damping=om[1], k3=om[2], k4=om[3])
        assert (backstepping_feedback(model, g) @ Tinv).ravel()[2] > target[2]


def test_reachable_case_optimizer_recovers_the_are_gain_and_its_poles():
    """With R = 1e-3 the LQR gain lies in the backstepping family: the optimiser's Omega, put through the
    hand derivation (16.3), equals the ARE gain of the flexible joint written down independently in
    Table 16.1's coordinates (scipy's Riccati solver, not the package's Drake LQR), so the closed loop
    has the LQR's poles; the Monte-Carlo search (300 draws in the same box) cannot reach that set.

    Model in x = [q, qd, tau, taud] (no damping, section 15.3): M qdd = tau, Bm thetadd = u - tau,
    tau = k (theta - q)  =>  taudd = k u / Bm - k (1/Bm + 1/M) tau.
    Tolerances: the fit's relative gain error is < 1e-8 (asserted); the ARE solution of this
    4-state problem is conditioned to ~1e-9 relative, so 1e-6 on gains and poles leaves margin."""
    from scipy.linalg import solve_continuous_are
    rig = table_16_1_rig()
    case = OptimalGainsCase(r_weight=1e-3)
    M, Bm, k = case.link_inertia, case.motor_inertia, case.stiffness
    A = np.array([[0, 1, 0, 0], [0, 0, 1 / M, 0], [0, 0, 0, 1], [0, 0, -k * (1 / Bm + 1 / M), 0]])
    B = np.array([[0.0], [0.0], [0.0], [k / Bm]])
    S = solve_continuous_are(A, B, np.diag(case.q_weights), np.array([[case.r_weight]]))
    K_are = (B.T @ S).ravel() / case.r_weight
    assert K_are[0] == pytest.approx(np.sqrt(case.q_weights[0] / case.r_weight), rel=1e-9)  # sqrt(Q11/R)
    fit = optimize_gains(rig, case)
    assert fit.distance < 1e-8
    g = fit.gains
    K_fit = _k_bs_closed_form(M, Bm, k, g.stiffness, g.damping, g.k3, g.k4)
    np.testing.assert_allclose(K_fit, K_are, rtol=1e-6)
    lqr_poles = np.sort_complex(np.linalg.eigvals(A - B @ K_are[None, :]))
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(A - B @ K_fit[None, :])), lqr_poles,
                               rtol=1e-6)
    assert all(lo <= v <= hi for v, lo, hi in zip((g.stiffness, g.damping, g.k3, g.k4), case.gain_low,
                                                   case.gain_high))
    with cf.ThreadPoolExecutor(2) as ex:
        mc = monte_carlo_gains(rig, case, samples=300, executor=ex)
    # the Monte-Carlo's reported distance is that of its own gains under (16.3), and it stays off the set
    gm = mc.gains
    K_mc = _k_bs_closed_form(M, Bm, k, gm.stiffness, gm.damping, gm.k3, gm.k4)
    assert mc.distance == pytest.approx(np.linalg.norm((K_mc - K_are) / np.abs(K_are)), rel=1e-5)
    assert mc.distance > 1e3 * max(fit.distance, 1e-12)


def test_torque_state_map_is_the_tendon_torque_jacobian_of_the_joint_rig():
    """N motors: T = d[q, qd, tau_i, taud_i]/dx at rest; tau_i = -P_i f_i from the rig's own tendon_force
    output (central differences), and for one torsion spring it is _torque_coordinates(k)."""
    from awiwi_drake.control.optimal_gains import torque_state_map
    from awiwi_drake.rigs import joint_rig
    rig = table_16_1_rig()
    np.testing.assert_allclose(torque_state_map(joint_model(rig), np.zeros(4)),
                               _torque_coordinates(OptimalGainsCase().stiffness), rtol=1e-12)
    rig = joint_rig()
    op = rig.operating_point()
    T = torque_state_map(joint_model(rig), op.state)
    ctx = rig.context(op)
    P = np.array([-rig.params.link_pulley_radius, rig.params.link_pulley_radius])

    def tau(x):
        ctx.SetContinuousState(x)
        return -P * rig.diagram.GetOutputPort("tendon_force").Eval(ctx)
    x0 = np.asarray(op.state, float)
    pos = [0, 2, 3]                          # positions: q, theta1, theta2
    np.testing.assert_allclose(T[2:4][:, pos], fd_jacobian(tau, x0, h=1e-7)[:, pos], rtol=1e-5, atol=1e-9)
    # rates: taud_i = -P_i k_i (r_m omega_i + P_i qd) has the same coefficients on (qd, omega_i)
    np.testing.assert_allclose(T[4:6][:, [1, 4, 5]], T[2:4][:, [0, 2, 3]], rtol=1e-12)


def test_optimal_backstepping_on_the_antagonistic_joint_rig():
    """Ch. 16 beyond the flexible joint: gains fitted to the joint rig's LQR (N = 2) at 20 N inside the
    3 kHz gain box; K_bs of the fit through the controller system equals the law's; the continuous closed
    loop (Drake Linearize of rig + controller) is stable and so is the loop sampled at 3 kHz (ZOH
    discretisation of the linearised rig, spectral radius < 1); in the default box the fit is closer but
    needs K3 ~ 1e4 1/s, which makes the 3 kHz sampled loop unstable."""
    from pydrake.systems.primitives import Linearize
    from scipy.linalg import expm

    from awiwi_drake.analysis import linearize
    from awiwi_drake.control.backstepping import impedance_controller
    from awiwi_drake.control.base import closed_loop
    from awiwi_drake.control.optimal_gains import rate_limited_case, torque_state_map
    from awiwi_drake.control.registry import controller_names
    from awiwi_drake.parameters.backstepping import JointRigOptimalGainsCase
    from awiwi_drake.rigs import joint_rig
    rig = joint_rig()
    op = rig.operating_point()
    lin = linearize(rig, op)
    fs = 3000.0
    M = expm(np.block([[lin.A, lin.B], [np.zeros((2, 8))]]) / fs)
    Ad, Bd = M[:6, :6], M[:6, 6:]

    def sampled_radius(gains):
        K = system_feedback(impedance_controller(rig, gains, external_torque="none"), op.state)
        return np.max(np.abs(np.linalg.eigvals(Ad - Bd @ K)))

    case = rate_limited_case(JointRigOptimalGainsCase(), rig.params.link_inertia, fs)
    fit = optimize_gains(rig, case, starts=16)
    g = fit.gains
    assert fit.target.shape == (2, 6) and np.isfinite(fit.distance)
    assert g.k3 <= fs / 4 * (1 + 1e-9) and g.k4 <= fs / 4 * (1 + 1e-9)
    assert g.damping <= rig.params.link_inertia * fs / 4 * (1 + 1e-9)
    ctrl = impedance_controller(rig, g, external_torque="none")
    K_sys = system_feedback(ctrl, op.state)
    T_inv = np.linalg.inv(torque_state_map(joint_model(rig), op.state))
    np.testing.assert_allclose(K_sys @ T_inv, fit.feedback, rtol=1e-9, atol=1e-9 * np.abs(fit.feedback).max())
    loop = closed_loop(rig, ctrl, rate_hz=None)
    ctx = loop.create_context(state=op.state, motor_torque=op.motor_torque, references={"joint_angle_reference": 0.0})
    d = loop.diagram
    cl = Linearize(d, ctx, input_port_index=d.GetInputPort("joint_angle_reference").get_index(),
                   output_port_index=d.GetOutputPort("joint_angle").get_index())
    assert np.max(np.linalg.eigvals(cl.A()).real) < 0
    assert sampled_radius(g) < 1.0
    free = optimize_gains(rig, JointRigOptimalGainsCase(r_weight=1e-6), starts=16)   # the default box
    assert free.distance < 0.5 * fit.distance and free.gains.k3 > 5e3
    assert sampled_radius(free.gains) > 1.0
    assert "optimal-backstepping" in controller_names("joint-rig")


def test_fig_16_3_table_16_2_weights_collapse_the_gains_and_every_reachable_selection_is_a_stable_unit_dc_loop():
    """Table 16.2 (= Table 16.1, R = 0.1): Algorithm 3's gains collapse (the target is below the
    structural floor, distance > 5) and the Fig 16.3 step moves the link by < 5 % of the step in the
    0.3 s in which Fig 16.3's trajectories reach their level.  With the reachable R every selected gain
    set (3 runs x 300 draws, seeds 0-2) gives a closed loop (Drake ``Linearize``) that is asymptotically
    stable (section 15.3: backstepping with positive gains) with unit DC gain reference -> q (no damping,
    no external torque: the link rests only where the impedance torque vanishes, q = q_ref), and the
    simulated link ends within the slowest mode's decay of the step."""
    from pydrake.systems.primitives import Linearize
    from awiwi_drake.control.backstepping import impedance_controller
    from awiwi_drake.control.base import closed_loop
    from awiwi_drake.parameters.backstepping import OptimalGainsStudy
    from awiwi_drake.reproductions.ch16_optimal_backstepping import fig_16_3_gain_samples
    study = OptimalGainsStudy(runs=3, samples=300)
    printed = fig_16_3_gain_samples(study.replace(runs=2, t_final=study.rise_time, num=31))
    assert np.all(np.abs(printed.q[:, -1]) < 0.05 * study.step)
    assert np.all(printed.distance > 5.0)                 # the structural floor (REPRODUCTIONS ch. 16)
    reach = fig_16_3_gain_samples(study, r_weight=study.reachable_r_weight)
    case = OptimalGainsCase(r_weight=study.reachable_r_weight)
    for g, q in zip(reach.gains, reach.q):
        rig = table_16_1_rig(case)
        loop = closed_loop(rig, impedance_controller(rig, g, external_torque="none"), rate_hz=None)
        d = loop.diagram
        ctx = loop.create_context(references={"joint_angle_reference": 0.0})
        cl = Linearize(d, ctx, input_port_index=d.GetInputPort("joint_angle_reference").get_index(),
                       output_port_index=d.GetOutputPort("joint_angle").get_index())
        eig = np.linalg.eigvals(cl.A())
        assert np.max(eig.real) < 0
        dc = (cl.D() - cl.C() @ np.linalg.solve(cl.A(), cl.B())).item()
        assert dc == pytest.approx(1.0, rel=1e-6)
        # modal bound of the stable linear loop from rest x0 to x_ss = -A^-1 B step:
        # |q(T) - step| = |C V exp(Lambda T) V^-1 (x0 - x_ss)| <= |C V| |V^-1 (x0 - x_ss)| exp(max Re l T)
        x0 = loop.create_context(references={"joint_angle_reference": study.step}).get_continuous_state_vector()
        x_ss = -np.linalg.solve(cl.A(), cl.B()).ravel() * study.step
        V = np.linalg.eig(cl.A())[1]
        bound = (np.linalg.norm(cl.C() @ V) * np.linalg.norm(np.linalg.solve(V, np.asarray(x0.CopyToVector()) - x_ss))
                 * np.exp(np.max(eig.real) * study.t_final))
        assert abs(q[-1] - study.step) <= bound + 1e-4 * study.step   # + the integrator's accuracy
