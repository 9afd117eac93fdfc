"""Tendon force distribution (ch. 7): Algorithm 2 and (7.6) as a Drake program, on the hand's own data.

Exact torque, bounds, explicit infeasibility, reachable stiffness found, the optimum checked
against an independent optimiser (scipy SLSQP, several starts) and never worse than Algorithm 2.
"""

import numpy as np
import pytest
from scipy.optimize import minimize

from awiwi_drake.components.spring import tendon_spring
from awiwi_drake.control.force_distribution import (
    OptimalForceDistribution, TendonForceDistribution, TendonForceDistributionSystem, _max_margin_alpha,
    coupling_nullspace,
    finger_force_distribution,
    hand_stiffness_map, stiffness_cost)
from awiwi_drake.components.tendon import joint_stiffness
from awiwi_drake.hand.coupling import finger_coupling, index_coupling_matrix
from awiwi_drake.parameters.hand import FingerDriveParams, IndexFingerParams
from awiwi_drake.parameters.hand_control import ForceDistributionParams
from _fd import fd_jacobian


def _index_P():
    return finger_coupling("index").P(np.zeros(4))


def _thumb(q):
    c = finger_coupling("thumb")
    return c.P(q), np.stack([c.tension_hessian(q, e) for e in np.eye(c.num_tendons)])


def _slsqp_optimum(P, H, tau, K_des, kmap, p, starts):
    """Independent solution of (7.6): scipy SLSQP from several starts, best feasible cost."""
    m = P.shape[0]
    def cost(f):
        return stiffness_cost(K_des, joint_stiffness(P, kmap(f)[0], f, H))
    best = np.inf
    for x0 in starts:
        r = minimize(cost, x0, method="SLSQP", bounds=[(p.f_min, p.f_max)] * m,
                     constraints=[{"type": "eq", "fun": lambda f: -P.T @ f - tau}],
                     options=dict(maxiter=500, ftol=1e-15))
        if np.linalg.norm(-P.T @ r.x - tau) < 1e-8 and np.all(r.x >= p.f_min - 1e-8) and np.all(r.x <= p.f_max + 1e-8):
            best = min(best, cost(r.x))
    return best


def test_hand_data_radii_and_spring_curve():
    """The finger solvers use the hand's radii (6, 8, 7, 5) mm and its calibrated spring law."""
    fd = finger_force_distribution("index")
    p = IndexFingerParams()
    radii = (p.abduction_radius, p.mcp_radius, p.pip_radius, p.dip_radius)
    assert radii == (0.006, 0.008, 0.007, 0.005)
    np.testing.assert_array_equal(fd._offline[0], index_coupling_matrix(*radii))
    spring = tendon_spring(FingerDriveParams().spring)
    kmap = hand_stiffness_map()
    for f in (5.0, 20.0, 80.0, 160.0):
        x = spring.inverse_force(f)
        assert kmap(np.array([f]))[0][0] == pytest.approx(float(spring.stiffness(x)), rel=2e-3)


def test_nullspace_produces_no_torque_and_pinv_inverts():
    P = _index_P()
    pinv_PT, W, rank = coupling_nullspace(P)
    assert rank == 4 and W.shape == (8, 4)
    np.testing.assert_allclose(P.T @ W, 0.0, atol=1e-15)
    np.testing.assert_allclose(P.T @ pinv_PT, np.eye(4), atol=1e-12)


@pytest.mark.parametrize("method", ["algorithm2", "optimal"])
def test_index_finger_exact_torque_bounds_and_reachable_stiffness(method):
    fd = finger_force_distribution("index", method=method)
    P, kmap, p = fd._offline[0], fd.stiffness_map, fd.params
    rng = np.random.default_rng(3)
    for _ in range(5):
        f_star = rng.uniform(20.0, 150.0, 8)
        tau = -P.T @ f_star                      # tau = -P^T f (ARCHITECTURE.md)
        K_des = joint_stiffness(P, kmap(f_star)[0], f_star)
        res = fd.solve(tau, K_des)
        assert res.status == "ok"
        assert res.torque_error < 1e-12 * max(1.0, np.linalg.norm(tau))   # numerical precision
        assert res.bound_violation == 0.0
        assert np.all(res.forces >= p.f_min) and np.all(res.forces <= p.f_max)
        assert res.stiffness_error < 1e-3        # a reachable stiffness is found
        assert np.all(np.linalg.eigvalsh(res.stiffness) > 0)


def test_optimal_solution_equals_an_independent_optimiser_and_beats_algorithm_2():
    """Unreachable stiffness (scaled away from any f): the Drake-program optimum equals the best of
    five SLSQP runs (rtol 1e-4) and Algorithm 2 stops measurably above it."""
    alg2 = finger_force_distribution("index", method="algorithm2")
    opt = finger_force_distribution("index")
    P, kmap, p = opt._offline[0], opt.stiffness_map, opt.params
    rng = np.random.default_rng(7)
    ratios = []
    for _ in range(4):
        f_star = rng.uniform(20.0, 150.0, 8)
        tau = -P.T @ f_star
        K_des = joint_stiffness(P, kmap(f_star)[0], f_star) * rng.uniform(0.4, 1.8, (4, 4))
        K_des = 0.5 * (K_des + K_des.T)
        a, b = alg2.solve(tau, K_des), opt.solve(tau, K_des)
        assert a.status == b.status == "ok" and b.torque_error < 1e-12 and b.bound_violation == 0.0
        ref = _slsqp_optimum(P, None, tau, K_des, kmap, p, [a.forces, f_star] + list(rng.uniform(10, 160, (3, 8))))
        assert b.cost <= ref * (1 + 1e-4) + 1e-12
        assert b.cost <= a.cost + 1e-12
        ratios.append(a.cost / b.cost)
    assert max(ratios) > 1.5                     # Algorithm 2 is not optimal on these requests


@pytest.mark.parametrize("method", ["algorithm2", "optimal"])
def test_infeasible_request_is_reported_not_clipped(method):
    fd = finger_force_distribution("index", method=method)
    tau = np.array([5.0, 0.0, 0.0, 0.0])          # needs ~400 N differences: outside [5, 170] N
    res = fd.solve(tau, np.eye(4))
    assert res.status == "infeasible"
    assert res.torque_error < 1e-12                # the torque is still exact ...
    assert res.bound_violation > 10.0              # ... and the violation is reported
    assert np.any(res.forces < fd.params.f_min)


def test_thumb_position_dependent_coupling_with_geometric_stiffness():
    """Thumb (P(q) of (5.20)-(5.22) and its tension Hessian): both solvers evaluate the coupling at
    q; the optimum equals SLSQP's; the geometric term is part of the achieved stiffness."""
    alg2 = finger_force_distribution("thumb", method="algorithm2")
    opt = finger_force_distribution("thumb")
    kmap, p = opt.stiffness_map, opt.params
    q = np.array([0.4, -0.3, 0.2, 0.1])
    P, H = _thumb(q)
    f_star = np.array([40.0, 70.0, 90.0, 60.0, 50.0, 30.0, 80.0, 60.0])
    K_reach = joint_stiffness(P, kmap(f_star)[0], f_star, H)
    for K_des, reachable in ((K_reach, True), (1.3 * K_reach + 0.2 * np.ones((4, 4)), False)):
        tau = -P.T @ f_star
        a, b = alg2.solve(tau, K_des, q=q), opt.solve(tau, K_des, q=q)
        for res in (a, b):
            assert res.status == "ok" and res.torque_error < 1e-12 and res.bound_violation == 0.0
        if reachable:
            # the optimum finds it; Algorithm 2 stops ~1.7 % off after its 60 halving steps
            assert b.stiffness_error < 1e-6 and a.stiffness_error > 100 * b.stiffness_error
        else:
            ref = _slsqp_optimum(P, H, tau, K_des, kmap, p, [a.forces, f_star])
            assert b.cost <= ref * (1 + 1e-4) and b.cost <= a.cost
    assert np.linalg.norm(joint_stiffness(P, kmap(b.forces)[0], b.forces) - b.stiffness) > 1e-3


def test_warm_start_inside_a_loop():
    """A slowly moving request at 3 kHz: one warm-started QP per period stays feasible with exact
    torque and keeps the cost within 1e-6 (relative) of the fully converged optimum."""
    opt = finger_force_distribution("index")
    P, kmap = opt._offline[0], opt.stiffness_map
    f0 = np.array([40.0, 70.0, 90.0, 60.0, 50.0, 30.0, 80.0, 60.0])
    K0 = 1.4 * joint_stiffness(P, kmap(f0)[0], f0)
    f = opt.solve(-P.T @ f0, K0).forces
    for k in range(1, 31):
        t = k / 3000.0
        tau = -P.T @ f0 + 0.05 * np.sin(2 * np.pi * 2 * t) * np.array([1.0, 0.5, -0.3, 0.2])
        K_des = K0 * (1 + 0.2 * np.sin(2 * np.pi * t))
        warm = opt.solve(tau, K_des, warm_start=f, max_iterations=1)
        assert warm.status == "ok" and warm.torque_error < 1e-12 and warm.bound_violation == 0.0
        full = opt.solve(tau, K_des)
        assert warm.cost <= full.cost * (1 + 1e-6) + 1e-12
        f = warm.forces


def test_ring_uses_the_reduced_coupling():
    opt = finger_force_distribution("ring")
    P = opt._offline[0]
    assert P.shape == (6, 3)                       # P4 of section 5.3.3: independent DoF abd, MCP, PIP
    f = np.full(6, 30.0)
    res = opt.solve(-P.T @ f, joint_stiffness(P, opt.stiffness_map(f)[0], f))
    assert res.status == "ok" and res.stiffness_error < 1e-6


def test_bad_input_names_the_argument():
    fd = finger_force_distribution("index", method="algorithm2")
    with pytest.raises(ValueError, match="tau_des"):
        fd.solve(np.zeros(3), np.eye(4))
    with pytest.raises(ValueError, match="symmetric"):
        fd.solve(np.zeros(4), np.triu(np.ones((4, 4))))
    with pytest.raises(ValueError, match="coupling P"):
        TendonForceDistribution(hand_stiffness_map(), coupling=np.ones((2, 4)))
    with pytest.raises(ValueError, match="f_min"):
        ForceDistributionParams(f_min=100.0, f_max=50.0)
    with pytest.raises(ValueError, match="method"):
        finger_force_distribution("index", method="newton")
    with pytest.raises(ValueError, match="finger"):
        finger_force_distribution("sixth")
    opt = finger_force_distribution("thumb")
    with pytest.raises(ValueError, match="pass q"):
        opt.solve(np.zeros(4), np.eye(4))
    with pytest.raises(ValueError, match="warm_start"):
        finger_force_distribution("index").solve(np.zeros(4), np.eye(4), warm_start=np.ones(3))
    with pytest.raises(ValueError, match="max_iterations"):
        OptimalForceDistribution(hand_stiffness_map(), max_iterations=0)
    with pytest.raises(ValueError, match="fast_path = 'no'"):         # not read as a truthy string
        finger_force_distribution("index", fast_path="no")
    with pytest.raises(ValueError, match="solver_options"):
        finger_force_distribution("index", solver_options={"tol_feas": 1e-9})


def _ad_update(system, x, forces, n):
    from pydrake.autodiffutils import ExtractGradient, InitializeAutoDiff
    ad = system.ToAutoDiffXd()
    ctx = ad.CreateDefaultContext()
    xa = InitializeAutoDiff(x).ravel()
    ctx.SetDiscreteState(0, forces.astype(object) * 1.0)
    ad.GetInputPort("joint_torque_reference").FixValue(ctx, xa[:n])
    ad.GetInputPort("joint_stiffness_reference").FixValue(ctx, xa[n:])
    return ExtractGradient(ad.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector(0).CopyToVector())


@pytest.mark.parametrize("tau, K_diag", [((0.1, 0.05, -0.03, 0.02), (8.0, 12.0, 6.0, 2.0)),
                                         ((0.05, -0.02, 0.03, 0.01), (2.0, 3.0, 1.5, 0.6))])
def test_system_autodiff_is_the_derivative_of_the_optimum(tau, K_diag):
    """ToAutoDiffXd of the loop system: d(forces)/d(tau, K) from the implicit-function theorem equals
    central differences of the fully converged float optimum (the second request has two tendons
    on f_min: the active set is held)."""
    system = TendonForceDistributionSystem(fingers=("index",), iterations_per_period=30)
    s = finger_force_distribution("index", max_iterations=100, tolerance=1e-15)
    x = np.concatenate([tau, K_diag])
    res = s.solve(x[:4], np.diag(x[4:]))
    J = _ad_update(system, x, res.forces, 4)
    J_fd = fd_jacobian(lambda y: s.solve(y[:4], np.diag(y[4:]), warm_start=res.forces).forces, x,
                       h=1e-5 * np.maximum(1.0, np.abs(x)))
    assert np.abs(J_fd).max() > 1.0
    np.testing.assert_allclose(J, J_fd, atol=1e-2 * np.abs(J_fd).max())


def test_system_update_is_the_warm_started_solver_and_reports_status():
    system = TendonForceDistributionSystem(fingers=("index", "thumb"), iterations_per_period=2)
    assert [system.get_input_port(i).get_name() for i in range(3)] == [
        "joint_torque_reference", "joint_stiffness_reference", "joint_angle"]
    ctx = system.CreateDefaultContext()
    tau = np.array([0.05, -0.02, 0.03, 0.01, 0.02, 0.01, -0.01, 0.0])
    K = np.array([2.0, 3.0, 1.5, 0.6, 3.0, 3.0, 2.0, 1.0])
    q = np.array([0.3, -0.2, 0.1, 0.1])
    system.GetInputPort("joint_torque_reference").FixValue(ctx, tau)
    system.GetInputPort("joint_stiffness_reference").FixValue(ctx, K)
    system.GetInputPort("joint_angle").FixValue(ctx, np.concatenate([np.zeros(4), q]))
    f0 = ctx.get_discrete_state(0).CopyToVector()
    upd = system.EvalUniquePeriodicDiscreteUpdate(ctx)
    idx, th = finger_force_distribution("index"), finger_force_distribution("thumb")
    np.testing.assert_allclose(upd.get_vector(0).CopyToVector()[:8],
                               idx.solve(tau[:4], np.diag(K[:4]), warm_start=f0[:8], max_iterations=2).forces)
    np.testing.assert_allclose(upd.get_vector(0).CopyToVector()[8:],
                               th.solve(tau[4:], np.diag(K[4:]), q=q, warm_start=f0[8:], max_iterations=2).forces)
    np.testing.assert_array_equal(upd.get_vector(1).CopyToVector(), [0.0, 0.0])
    system.GetInputPort("joint_torque_reference").FixValue(ctx, np.concatenate([[5.0, 0, 0, 0], tau[4:]]))
    np.testing.assert_array_equal(system.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector(1).CopyToVector(),
                                  [1.0, 0.0])                     # the infeasible index request is reported
    with pytest.raises(ValueError, match="stiffness"):
        TendonForceDistributionSystem(stiffness="sparse")


@pytest.mark.parametrize("method", ["optimal", "algorithm2"])
def test_system_runs_at_3khz_in_a_simulator_with_the_thumb(method):
    """The thumb's position-dependent distribution inside a Drake Simulator at 3 kHz (one warm-started
    QP per period for the optimal solver; Algorithm 2's iterations from the previous forces): a sinusoidal
    torque request and a moving posture; after each periodic update the held forces produce the request
    sampled at that update exactly (-P(q_k)^T f = tau_k) and stay in the bounds (issue 10 item 7)."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource, Sine

    from awiwi_drake.hand.coupling import finger_coupling
    b = DiagramBuilder()
    fd = b.AddSystem(TendonForceDistributionSystem(fingers=("thumb",), method=method, iterations_per_period=1))
    tau0 = np.array([0.02, 0.01, -0.01, 0.005])
    tau = b.AddSystem(Sine(0.01 * np.ones(4), 2 * np.pi * 5 * np.ones(4), np.zeros(4)))
    from pydrake.systems.primitives import Adder
    add = b.AddSystem(Adder(2, 4))
    off = b.AddSystem(ConstantVectorSource(tau0))
    b.Connect(tau.get_output_port(0), add.get_input_port(0))
    b.Connect(off.get_output_port(), add.get_input_port(1))
    b.Connect(add.get_output_port(), fd.GetInputPort("joint_torque_reference"))
    K = b.AddSystem(ConstantVectorSource(np.array([3.0, 3.0, 2.0, 1.0])))
    b.Connect(K.get_output_port(), fd.GetInputPort("joint_stiffness_reference"))
    q = b.AddSystem(Sine(np.array([0.3, 0.2, 0.0, 0.0]), 2 * np.pi * 2 * np.ones(4), np.zeros(4)))
    b.Connect(q.get_output_port(0), fd.GetInputPort("joint_angle"))
    d = b.Build()
    sim = Simulator(d)
    ctx = sim.get_mutable_context()
    c = finger_coupling("thumb")
    p = fd.solvers[0].params
    fctx = fd.GetMyContextFromRoot(ctx)
    for k in range(1, 16):
        t_prev = k / 3000.0                      # the update at t_k samples the inputs at t_k
        sim.AdvanceTo(t_prev + 1e-9)
        f = fd.GetOutputPort("tendon_force_reference").Eval(fctx)
        request = tau0 + 0.01 * np.sin(2 * np.pi * 5 * t_prev)
        q_prev = np.array([0.3, 0.2, 0.0, 0.0]) * np.sin(2 * np.pi * 2 * t_prev)
        np.testing.assert_allclose(-c.P(q_prev).T @ f, request, atol=1e-12)
        assert np.all(f >= p.f_min - 1e-9) and np.all(f <= p.f_max + 1e-9)
        assert fd.GetOutputPort("distribution_status").Eval(fctx)[0] == 0.0


def test_algorithm2_system_autodiff_carries_the_exact_torque_part():
    """Algorithm 2 in the system: its derivative w.r.t. the torque request is -(P^T)^+ (the exact-torque
    part; the internal forces of the step-halving search carry none): closed form."""
    from pydrake.autodiffutils import ExtractGradient, InitializeAutoDiff
    system = TendonForceDistributionSystem(fingers=("index",), method="algorithm2")
    ad = system.ToAutoDiffXd()
    ctx = ad.CreateDefaultContext()
    x = InitializeAutoDiff(np.array([0.05, -0.02, 0.03, 0.01])).ravel()
    ad.GetInputPort("joint_torque_reference").FixValue(ctx, x)
    ad.GetInputPort("joint_stiffness_reference").FixValue(ctx, np.array([2.0, 3.0, 1.5, 0.6]))
    J = ExtractGradient(ad.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector(0).CopyToVector())
    P = _index_P()
    np.testing.assert_allclose(J, -np.linalg.pinv(P.T), atol=1e-12)


def test_algorithm2_warm_start_never_loses_what_it_had():
    """Algorithm 2 warm-started at its previous forces (the in-loop use): the same request ends at a cost
    no higher than before (accepted steps only lower it); a wrong-sized warm start is named."""
    fd = finger_force_distribution("thumb", method="algorithm2")
    q = np.array([0.2, -0.1, 0.1, 0.0])
    tau = np.array([0.02, 0.01, -0.01, 0.005])
    K = np.diag([3.0, 3.0, 2.0, 1.0])
    first = fd.solve(tau, K, q=q)
    again = fd.solve(tau, K, q=q, warm_start=first.forces)
    assert again.status == "ok" and again.torque_error < 1e-12
    assert again.cost <= first.cost + 1e-15
    with pytest.raises(ValueError, match="warm_start"):
        fd.solve(tau, K, q=q, warm_start=np.ones(3))


def _tight_program_options():
    """Clarabel at tolerances tight enough to compare optima to 1e-9."""
    from pydrake.solvers import ClarabelSolver, SolverOptions
    opts = SolverOptions()
    for k in ("tol_gap_abs", "tol_gap_rel", "tol_feas", "tol_ktratio"):
        opts.SetOption(ClarabelSolver.id(), k, 1e-11)
    return opts


def _kkt(Q, b, P, tau):
    """Equality-constrained QP optimum from the full KKT system (independent of the solver's null-space form)."""
    m, n = P.shape
    A = -P.T
    KKT = np.block([[Q, A.T], [A, np.zeros((n, n))]])
    return np.linalg.lstsq(KKT, np.concatenate([-b, tau]), rcond=None)[0][:m]


@pytest.mark.parametrize("finger", ["index", "ring", "thumb"])
def test_closed_form_qp_equals_the_program_and_switches_exactly_at_the_bounds(finger):
    """The optimal solver's QP step: inside the bounds the closed-form (KKT) optimum equals the Drake
    MathematicalProgram's (Clarabel at tight tolerances) to 1e-9; a bound just below the closed-form
    optimum switches to the program, whose answer then respects it; just above, the closed form stays."""
    rng = np.random.default_rng(11)
    q = np.array([0.3, -0.2, 0.1, 0.2])
    for trial in range(4):
        fast = finger_force_distribution(finger)
        P, pinv_PT, W, rank, _ = fast._coupling_at(None, None, q if finger == "thumb" else None)
        m = P.shape[0]
        f = 60.0 + 30.0 * rng.uniform(-1, 1, m)                  # a feasible point (f_min 5, f_max 170)
        tau = -P.T @ f
        A = rng.normal(size=(m, m))
        Q = A @ A.T + 0.1 * np.eye(m)
        # unconstrained optimum f_target: another torque-exact point plus a 1 N push off the torque manifold
        f_target = f + W @ rng.uniform(-20, 20, W.shape[1]) + P @ rng.normal(scale=1.0 / np.abs(P).max(), size=P.shape[1])
        b = -Q @ f_target
        f_star = _kkt(Q, b, P, tau)
        assert np.all(f_star > 5.0) and np.all(f_star < 170.0)
        got, used = fast._qp(Q, b, f, W, P, tau, rank, [])
        assert not used
        np.testing.assert_allclose(got, f_star, rtol=0, atol=1e-9 * np.abs(f_star).max())
        prog = finger_force_distribution(finger, fast_path=False, solver_options=_tight_program_options())
        via, used = prog._qp(Q, b, f, W, P, tau, rank, [])
        assert used
        np.testing.assert_allclose(via, f_star, rtol=0, atol=1e-9 * np.abs(f_star).max())
        top = float(f_star.max())
        for f_max, expect_program in ((top * (1 + 1e-12), False), (top - 1e-6, True)):
            s = finger_force_distribution(finger, params=ForceDistributionParams(f_max=f_max),
                                          solver_options=_tight_program_options())
            f_p = -pinv_PT @ tau
            start = f_p + W @ _max_margin_alpha(f_p, W, 5.0, f_max)   # a feasible point under this bound
            x, used = s._qp(Q, b, start, W, P, tau, rank, [])
            assert used == expect_program
            assert x.max() <= f_max + 1e-8
            np.testing.assert_allclose(-P.T @ x, tau, atol=1e-9)


@pytest.mark.parametrize("finger", ["index", "fifth", "thumb"])
def test_fast_solver_equals_the_program_at_random_interior_states(finger):
    """Whole solves (several Gauss-Newton QPs, warm-started) at random requests whose optimum is inside the
    bounds: closed form and MathematicalProgram give the same forces to 1e-9 and the same iterations."""
    rng = np.random.default_rng(5)
    fast = finger_force_distribution(finger)
    prog = finger_force_distribution(finger, fast_path=False, solver_options=_tight_program_options())
    for trial in range(3):
        q = rng.uniform(-0.3, 0.3, 4) if finger == "thumb" else None
        P, _, _, _, H = fast._coupling_at(None, None, q)
        f0 = rng.uniform(30.0, 110.0, P.shape[0])
        K_des = rng.uniform(1.0, 1.3) * joint_stiffness(P, fast.stiffness_map(f0)[0], f0, H)
        tau = -P.T @ f0 + rng.normal(scale=0.02, size=P.shape[1])
        ws = f0 + rng.normal(scale=3.0, size=f0.size)
        kw = {} if q is None else dict(q=q)
        a = fast.solve(tau, K_des, warm_start=ws, max_iterations=4, **kw)
        b = prog.solve(tau, K_des, warm_start=ws, max_iterations=4, **kw)
        assert a.status == b.status == "ok" and a.iterations == b.iterations
        assert a.program_qps == 0 and b.program_qps == b.iterations > 0
        np.testing.assert_allclose(a.forces, b.forces, rtol=0, atol=1e-9 * np.abs(b.forces).max())


def test_thumb_tension_hessians_are_the_derivative_of_the_coupling():
    """d^2 h_i/dq^2 of every thumb tendon (vectorised float path) against central differences of P(q)."""
    c = finger_coupling("thumb")
    q = np.array([0.35, -0.25, 0.3, 0.1])
    H = c.tension_hessians(q)
    assert H.shape == (8, 4, 4)
    for i in range(8):
        np.testing.assert_allclose(H[i], fd_jacobian(lambda qq: c.P(qq)[i], q, h=1e-6), atol=1e-8)
    f = np.linspace(10.0, 80.0, 8)
    np.testing.assert_allclose(np.einsum("i,ijk->jk", f, H), c.tension_hessian(q, f), atol=1e-14)


@pytest.mark.parametrize("laws", ["one", "per-tendon"])
def test_hand_system_batches_the_fingers_and_equals_each_fingers_solver(laws):
    """The loop system iterates all five fingers at once (float path); at random requests, near the design
    point (batched) and at the bounds (left to the finger's own solver: LP start, MathematicalProgram), the
    update equals each finger's warm-started solve to 1e-12.  Also with a spring law per tendon (two
    tendons overridden: the batch interpolates each tendon's own table row)."""
    fingers = ("thumb", "index", "middle", "ring", "fifth")
    springs = None
    if laws == "per-tendon":
        from awiwi_drake.components.spring import TendonSprings, tendon_spring
        from awiwi_drake.parameters.components import TendonParams
        from awiwi_drake.parameters.hand import FingerDriveParams
        nominal = FingerDriveParams().spring
        a, b = tendon_spring(nominal), tendon_spring(nominal.replace(tendon=TendonParams(diameter=2.0e-3)))
        springs = TendonSprings([b if i in (2, 11) else a for i in range(38)])   # thumb h3, index h4
    system = TendonForceDistributionSystem(fingers=fingers, iterations_per_period=2, stiffness="full",
                                           springs=springs)
    assert system._batch is not None
    if springs is not None:
        assert system.solvers[0].stiffness_map.per_tendon and not system.solvers[2].stiffness_map.per_tendon
    rng = np.random.default_rng(3)
    ctx = system.CreateDefaultContext()
    served = left = 0
    for trial in range(6):
        q = np.concatenate([rng.uniform(-0.3, 0.3, 4), np.zeros(17)])
        taus, Ks, f_prev = [], [], []
        for k, (s, sd, st, sk, sq) in enumerate(system._parts):
            P, _, _, _, H = s._coupling_at(None, None, q[sq] if s._offline is None else None)
            f0 = rng.uniform(30.0, 110.0, P.shape[0])
            scale = 1.2 if trial % 2 == 0 else 40.0              # 40x: the optimum presses on a bound
            Ks.append(scale * joint_stiffness(P, s.stiffness_map(f0)[0], f0, H))
            taus.append(-P.T @ f0 + rng.normal(scale=0.01, size=P.shape[1]))
            f_prev.append(f0 + rng.normal(scale=2.0, size=f0.size) if trial != 5 else np.full(f0.size, 200.0))
        system.GetInputPort("joint_torque_reference").FixValue(ctx, np.concatenate(taus))
        system.GetInputPort("joint_stiffness_reference").FixValue(ctx, np.concatenate([K.ravel() for K in Ks]))
        system.GetInputPort("joint_angle").FixValue(ctx, q)
        ctx.SetDiscreteState(0, np.concatenate(f_prev))
        got = system.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector(0).CopyToVector()
        _, fallback = system._batch.update(np.concatenate(taus), np.concatenate([K.ravel() for K in Ks]),
                                           np.concatenate(f_prev), q, 2)
        served, left = served + int(np.sum(~fallback)), left + int(np.sum(fallback))
        for k, (s, sd, st, sk, sq) in enumerate(system._parts):
            kw = {} if s._offline is not None else dict(q=q[sq])
            ref = s.solve(taus[k], Ks[k], warm_start=f_prev[k], max_iterations=2, **kw).forces
            np.testing.assert_allclose(got[st], ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max(), err_msg=s)
    assert served > 0 and left > 0


def test_chain_runs_once_per_control_period_never_in_derivative_evaluations(monkeypatch):
    """The cascaded chain (distribution, estimator, tendon force law) is sampled: over N control periods of
    fixed-step RK3 it is evaluated N (+1 at the start) times while the plant's derivatives are evaluated 3N."""
    from awiwi_drake.analysis import simulate
    from awiwi_drake.control import closed_loop, get_entry, make_controller
    from awiwi_drake.control.base import StaticLawController_
    from awiwi_drake.control.force_distribution import TendonForceDistribution_
    from awiwi_drake.hand.diagrams import finger_diagram
    from awiwi_drake.hand.dynamics import HandDynamics_
    from awiwi_drake.hand.estimation import LinkPositionEstimator_
    counts = {}

    def counting(cls, name):
        f = getattr(cls, name)

        def w(self, *a):
            counts[cls.__name__ + name] = counts.get(cls.__name__ + name, 0) + 1
            return f(self, *a)
        monkeypatch.setattr(cls, name, w)
    for cls, name in ((TendonForceDistribution_[float], "_update"), (LinkPositionEstimator_[float], "_update"),
                      (StaticLawController_[float], "_calc"), (HandDynamics_[float], "DoCalcTimeDerivatives")):
        counting(cls, name)
    rig = finger_diagram(finger="index")
    loop = closed_loop(rig, make_controller("cascaded", rig), **get_entry("cascaded", rig).loop_options)
    op = rig.operating_point()
    n = 12
    counts.clear()                          # the design (per-joint linearisations) evaluates the laws too
    simulate(loop, loop.create_context(op), n / loop.rate_hz, inputs={"joint_angle_reference": op.joint_angle + 0.02})
    derivs = counts.pop(HandDynamics_[float].__name__ + "DoCalcTimeDerivatives")
    assert 3 * n <= derivs <= 3 * n + 3
    for key, k in counts.items():
        assert n <= k <= n + 1, (key, k)


def test_shared_stiffness_map_is_read_only():
    """hand_stiffness_map returns one map per spring to every diagram: writing its table must fail, not
    change every other finger's stiffness."""
    kmap = hand_stiffness_map()
    assert hand_stiffness_map() is kmap
    for a in (kmap.forces, kmap.k, kmap.dk):
        with pytest.raises(ValueError, match="read-only"):
            a[0] = 1.0
