"""A spring law per tendon through the chain (issue 10 item 4): the hand's calibration table
(``params.tendon_springs``) reaches the chain's force maps and gains (10.11), the force distribution's
stiffness table ``k_t,i(f)`` and the per-joint reduced models, each tendon with its own curve
(``components.spring.TendonSprings``, the one place a vector of tendons meets its laws).

The overridden tendon is a 2 mm instead of a 1 mm tendon in series with the same lever mechanism
(``TendonParams(diameter=2e-3)``: four times the section, so a stiffer series spring, ch. 4)."""

import numpy as np
import pytest
from pydrake.autodiffutils import AutoDiffXd, InitializeAutoDiff, ExtractGradient, ExtractValue
from pydrake.systems.primitives import Linearize
from scipy.optimize import brentq

from _finger_laws import compiled, ideal_drive_derivatives
from awiwi_drake.components.spring import TendonSprings, tendon_spring
from awiwi_drake.control import closed_loop
from awiwi_drake.control.chain import TendonChainController, TendonForceStage, rig_springs
from awiwi_drake.control.design import ChainDesign
from awiwi_drake.control.force_distribution import OptimalForceDistribution, TendonStiffnessMap
from awiwi_drake.control.joint_design import design_joint_stage, design_motor, joint_subsystem, reduced_joint_models
from awiwi_drake.control.joint_stage import JointStateFeedbackLaw
from awiwi_drake.control.tendon_force import ForceMap, TendonForceLaw
from awiwi_drake.hand.diagrams import finger_diagram
from awiwi_drake.parameters.components import TendonParams
from awiwi_drake.parameters.hand import FingerRigParams
from awiwi_drake.parameters.hand_control import ForceDistributionParams, HandChainParams

STIFF = TendonParams(diameter=2.0e-3)


def _laws():
    nominal = FingerRigParams.for_finger("index").spring
    return tendon_spring(nominal), tendon_spring(nominal.replace(tendon=STIFF))


def _k_of_force(law, f):
    """k_t(f) of one law in closed form: its stiffness at the elongation that carries f."""
    return float(np.ravel(law.stiffness(np.ravel(law.inverse_force(np.array([f])))))[0])


def _mixed_rig(finger="index", tendon="index_h3"):
    """The finger with ``tendon``'s law overridden (the ideal drive without hysteresis and guide friction, as the
    per-joint design models; the design model's motor)."""
    p = FingerRigParams.for_finger(finger).with_physics(hysteresis=False, guide_friction=False)
    p = p.replace(motor=design_motor(p.motor), tendon_springs=((tendon, p.spring.replace(tendon=STIFF)),))
    return finger_diagram(finger=finger, params=p)


def test_tendon_springs_evaluate_each_tendon_with_its_own_law_for_float_and_autodiff():
    a, b = _laws()
    springs = TendonSprings([a, b, a])
    assert not springs.uniform and len(springs.groups) == 2 and TendonSprings([a, a]).uniform
    x = np.array([1.2e-3, 0.9e-3, 2.0e-3])
    for method in ("force", "stiffness", "stiffness_derivative", "energy"):
        want = [float(np.ravel(getattr(law, method)(np.array([xi])))[0]) for law, xi in zip(springs, x)]
        np.testing.assert_allclose(getattr(springs, method)(x), want, rtol=1e-14)
    f = np.array([10.0, 40.0, 90.0])
    np.testing.assert_allclose(springs.force(springs.inverse_force(f)), f, rtol=1e-9)
    # AutoDiffXd passes through: d f_i / d x_j = diag(k_i(x_i))
    xa = InitializeAutoDiff(x).ravel()
    fa = springs.force(xa)
    np.testing.assert_allclose(ExtractValue(fa).ravel(), springs.force(x), rtol=1e-14)
    np.testing.assert_allclose(ExtractGradient(fa), np.diag(springs.stiffness(x)), rtol=1e-12)
    assert isinstance(fa[0], AutoDiffXd)
    with pytest.raises(ValueError, match=r"one value per tendon \(3\)"):
        springs.force(x[:2])
    np.testing.assert_allclose(springs.subset([1]).force(x[1:2]), b.force(x[1:2]), rtol=1e-14)


def test_distribution_on_a_two_tendon_joint_uses_each_tendons_curve():
    """Closed form on the antagonistic joint h = [-r q, r q]: the exact torque fixes f1 - f2 = tau / r,
    and the stiffness r^2 (k_1(f1) + k_2(f2)) (5.12) grows with the co-contraction, so the optimum of (7.6)
    is the unique f2 with r^2 (k_a(f2 + tau/r) + k_b(f2)) = K_des (brentq on the two laws). The solver
    with the per-tendon table reaches it (stiffness error ~0); with the first law for both tendons it
    lands elsewhere (the check can fail)."""
    a, b = _laws()
    r, tau = 8e-3, 0.05
    P = np.array([[-r], [r]])

    def K_of(f2):
        return r * r * (_k_of_force(a, f2 + tau / r) + _k_of_force(b, f2))

    K_des = K_of(40.0) * 1.0           # a stiffness the pair can reach at 40 N on tendon 2
    f2 = brentq(lambda x: K_of(x) - K_des, 6.0, 150.0, xtol=1e-12)
    want = np.array([f2 + tau / r, f2])
    assert f2 == pytest.approx(40.0, rel=1e-9)
    params = ForceDistributionParams()
    res = OptimalForceDistribution(TendonStiffnessMap.from_springs(TendonSprings([a, b])), params, P).solve(
        np.array([tau]), np.array([[K_des]]))
    assert res.status == "ok"
    assert res.torque_error < 1e-12                                  # the exact torque
    np.testing.assert_allclose(res.forces, want, rtol=1e-5)
    # the achieved stiffness is each tendon's own curve at its force (table vs law: 1e-6)
    assert res.stiffness[0, 0] == pytest.approx(r * r * (_k_of_force(a, res.forces[0]) + _k_of_force(b, res.forces[1])),
                                                rel=1e-6)
    assert res.stiffness_error < 1e-5
    wrong = OptimalForceDistribution(TendonStiffnessMap.from_springs(TendonSprings([a, a])), params, P).solve(
        np.array([tau]), np.array([[K_des]]))
    assert np.abs(wrong.forces - want).max() > 1.0, wrong.forces      # the common law: another co-contraction


def test_chain_force_stage_uses_each_tendons_slope_and_names_a_bad_tendon():
    """The (10.2) bank built by the chain: tendon i's scheduled gains are (10.11) with its own slope
    alpha_i = r_m k_t,i(f); the bank equals the one-tendon law of each tendon's own map to 1e-12; an
    infeasible reference is named by its index in the bank."""
    rig = _mixed_rig()
    springs = rig_springs(rig)
    i3 = rig.tendon_names.index("index_h3")
    assert not springs.uniform and springs[i3] is not springs[0]
    stage = TendonForceStage(rig.coupling, springs, rig.params, HandChainParams(), point=ChainDesign(
                             np.eye(4), np.zeros((8, 4)), np.full(8, 20.0), np.zeros(4)), distribution="sharing")
    law = stage.GetSubsystemByName("tendon_force_control").law
    r_m, B = rig.params.motor.pulley_radius, rig.params.motor.inertia
    w, xi = stage.gains.natural_frequency, stage.gains.damping_ratio
    f = np.linspace(15.0, 120.0, 8)
    kp, kd = law.gains_at(f)
    alpha = r_m * springs.stiffness(springs.inverse_force(f))
    np.testing.assert_allclose(kp, w * w * B / alpha, rtol=1e-4)      # table vs law
    np.testing.assert_allclose(kd, 2 * xi * w * B / alpha, rtol=1e-4)
    assert kp[i3] < 0.9 * w * w * B / (r_m * _k_of_force(springs[0], f[i3]))   # stiffer tendon: smaller gain
    rng = np.random.default_rng(2)
    u = {"tendon_force_reference": f, "tendon_force": f + rng.normal(0, 2, 8), "motor_velocity": rng.normal(0, 3, 8),
         "motor_angle": rng.uniform(-2, 2, 8), "tendon_path_velocity": rng.normal(0, 0.01, 8)}
    u = {k_: v for k_, v in u.items() if k_ in law.inputs}
    got = law(u)
    for i in range(8):
        one = TendonForceLaw(ForceMap.from_spring(springs[i], r_m), rig.params.motor, stage.gains,
                             scheduled=law.scheduled, ripple_scale=law.ripple_scale if hasattr(law, "ripple_scale") else 0.0,
                             path_velocity="tendon_path_velocity" in law.inputs)
        assert got[i] == pytest.approx(one({k_: v[i:i + 1] for k_, v in u.items()})[0], rel=1e-12, abs=1e-12)
    with pytest.raises(ValueError, match=r"tendon_force_reference\[5\] = -1.0 N"):
        law(dict(u, tendon_force_reference=np.where(np.arange(8) == 5, -1.0, f)))


def test_reduced_model_torque_row_has_the_per_tendon_stiffness():
    """Each DoF's reduced model on the finger with one tendon's law overridden: the restriction stays exact
    (every tendon's force loop has the same dynamics, (10.11) with its own slope) and the torque row is
    tau'' = w^2 tau_ref - (w^2 + K_jj / M_jj) tau + ... with K_jj = sum_i P_ij^2 k_t,i(f_i) of each tendon's
    own law (5.12); the MCP, which h3 drives, differs from the common-law value."""
    rig = _mixed_rig()
    w = HandChainParams().force_bandwidth
    op = rig.operating_point()
    laws = rig_springs(rig)
    P = np.asarray(rig.coupling.P(op.joint_angle))
    k_own = np.array([_k_of_force(law, f) for law, f in zip(laws, op.tendon_force)])
    k_common = np.array([_k_of_force(laws[0], f) for f in op.tendon_force])
    # the gains (10.11) use each tendon's tabulated slope: tendon i's loop runs at w^2 (1 + e_i), e_i the
    # table's relative error at f_i; the restriction is exact up to the spread of e_i over the DoF's tendons
    r_m = rig.params.motor.pulley_radius
    e = np.array([float(ForceMap.from_spring(law, r_m).alpha_of_force(f)) / (r_m * k) - 1.0
                  for law, f, k in zip(laws, op.tendon_force, k_own)])
    for m in reduced_joint_models(rig):
        K_jj = float(P[:, m.dof] ** 2 @ k_own)
        spread = np.ptp(e[list(m.tendons)])
        assert m.invariance_residual < max(spread, 1e-12), (m.name, m.invariance_residual, spread)
        assert m.stiffness == pytest.approx(K_jj, rel=1e-9)
        assert m.B[3, 0] == pytest.approx(w ** 2, rel=1e-5)
        assert m.A[3, 2] == pytest.approx(-(w ** 2 + K_jj / m.inertia), rel=1e-5)
        if m.name == "q21":
            K_c = float(P[:, m.dof] ** 2 @ k_common)
            assert abs(K_jj - K_c) > 0.02 * K_c                     # the override matters here (2.9 % at 20 N)
            assert abs(m.A[3, 2] + (w ** 2 + K_c / m.inertia)) > 1e3 * 1e-5 * abs(m.A[3, 2])


@pytest.mark.parametrize("design", ["cascaded", "lqr"])
def test_one_joint_with_mixed_laws_closed_by_the_chain_has_exactly_the_designed_poles(design):
    """The MCP (driven by h1-h4, h3 overridden) as its one-DoF subsystem closed by the whole chain (joint
    stage, sharing, the (10.2) bank with each tendon's map): Drake's Linearize has the designed poles."""
    rig = _mixed_rig()
    d = design_joint_stage(rig, design)
    j = 1
    sub, op, point = joint_subsystem(rig, j)
    assert not rig_springs(sub).uniform                           # the subsystem carries the two laws
    K = d.gains[j, :4]
    law = JointStateFeedbackLaw(sub.coupling, np.eye(1), rig.params.motor.pulley_radius, K[None, :],
                                state_map=d.law.Nx[j:j + 1], input_map=d.law.Nu[j:j + 1], joint_angle_op=[0.0],
                                torque_op=point.torque_offset, torque_rate=d.law.torque_rate)
    loop = closed_loop(sub, TendonChainController(sub, law, point=point, distribution="sharing"), rate_hz=None,
                       estimator=None)
    ctx = loop.create_context(op, references={"joint_angle_reference": [0.0]})
    # the operating point: each tendon carries its force through its own law (up to inverse_force's 1e-13)
    f = loop.diagram.GetOutputPort("tendon_force").Eval(ctx)
    np.testing.assert_allclose(f, op.tendon_force, rtol=1e-12)
    lin = Linearize(loop.diagram, ctx, input_port_index=loop.diagram.GetInputPort("joint_angle_reference").get_index(),
                    output_port_index=loop.diagram.GetOutputPort("joint_angle").get_index())
    actual = np.linalg.eigvals(lin.A())
    m = d.models[j]
    # exact but for the force maps' tables: tendon i's loop runs at w^2 (1 + e_i) (e_i: its slope table's
    # relative error at f_i, ~1e-7, different for the two laws), a relative perturbation of the design's
    # dynamics of at most spread(e); Bauer-Fike: |d lambda| <= cond(V) spread ||F - G K||
    r_m = rig.params.motor.pulley_radius
    laws = rig_springs(sub)
    e = np.array([float(ForceMap.from_spring(law, r_m).alpha_of_force(f)) / (r_m * k) - 1.0
                  for law, f, k in zip(laws, op.tendon_force, laws.stiffness(op.elongation))])
    from scipy.linalg import matrix_balance
    Acl, _ = matrix_balance(m.A - m.B @ K[None, :])       # a diagonal similarity: same poles, same relative
    lam_d, V = np.linalg.eig(Acl)                         # perturbation of the entries, smaller cond(V)
    bound = np.linalg.cond(V) * np.ptp(e) * np.linalg.norm(Acl, 2)
    assert bound < 1e-3 * np.abs(lam_d).min()                      # a bound that can fail
    for lam in lam_d:
        assert np.min(np.abs(actual - lam)) < 1e-8 * abs(lam) + bound, (lam, actual, bound)
    assert np.all(actual.real < 0)


def test_two_time_scale_tendon_level_damps_the_elongation_rate_with_each_tendons_stiffness():
    """The two-time-scale chain's tendon level (11.3) on the finger with one law overridden, closed form of each
    DoF's reduced model (Kp_m = B w_m^2, Kd_m = 2 xi w_m B at the chain's force bandwidth; per tendon: B thdd = Kp_m (f_d - f) / alpha_i - Kd_m (thd + v_path / r_m) - d_eff thd,
    alpha_i = r_m k_i, f = phi_i(r_m th + P q)): tau'' = w_m^2 (tau_d - tau) - (Kd_m + d_eff)/B tau'
    - K_jj qdd - K_jj d_eff/B qd with K_jj = sum_i P_ij^2 k_i (each tendon's own law), qdd = (tau - b qd)/M;
    d_eff = d (1 - friction_scale) (the law feeds forward friction_scale of the motor's viscous term).  Damping
    the absolute motor velocity instead would add -K_jj Kd_m / B to the qd entry: a viscous joint damping that
    made the finger designs crawl (slowest index pole -0.35 1/s)."""
    from awiwi_drake.parameters.control import TendonForceGains
    rig = _mixed_rig()
    op = rig.operating_point()
    laws = rig_springs(rig)
    P = np.asarray(rig.coupling.P(op.joint_angle))
    k_own = np.array([_k_of_force(law, f) for law, f in zip(laws, op.tendon_force)])
    motor = rig.params.motor       # the motor loop runs at the chain's force bandwidth and damping ratio
    B, wm = motor.inertia, HandChainParams().force_bandwidth
    kd_m = 2 * TendonForceGains().damping_ratio * wm * B
    d_eff = (motor.damping + (motor.viscous_friction if motor.friction else 0.0)) * (1 - HandChainParams().friction_scale)
    for m in reduced_joint_models(rig, tendon_law="motor-position"):
        K_jj = float(P[:, m.dof] ** 2 @ k_own)
        assert m.invariance_residual < 1e-12, (m.name, m.invariance_residual)   # no table: alpha_i from k_i itself
        want = [K_jj * (m.damping / m.inertia - d_eff / B), -(wm ** 2 + K_jj / m.inertia), -(kd_m + d_eff) / B]
        got = [m.A[3, 1], m.A[3, 2], m.A[3, 3]]
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * abs(want[1]))
        assert m.B[3, 0] == pytest.approx(wm ** 2, rel=1e-12)
        assert abs(K_jj * kd_m / B) > 1e3 * 1e-9 * abs(want[1])              # the absolute damping would show


def test_hand_chain_gives_every_finger_its_own_tendons_laws():
    """On the hand (38 tendons, the distribution one solver per finger, the force law one bank) with laws
    overridden in two fingers: every tendon's distribution table row and force map are its own law's (the
    fingers' slices of the hand's laws line up with their tendons)."""
    from awiwi_drake.hand.diagrams import hand_diagram
    from awiwi_drake.parameters.hand import HandRigParams
    from awiwi_drake.control import make_controller
    p = HandRigParams()
    stiff = p.spring.replace(tendon=STIFF)
    hand = hand_diagram(wrist=False, params=p.replace(tendon_springs=(("middle_h3", stiff), ("thumb_h8", stiff))))
    springs = rig_springs(hand)
    over = [hand.tendon_names.index(t) for t in ("middle_h3", "thumb_h8")]
    assert [i for i, law in enumerate(springs) if law is not springs[0]] == sorted(over)
    ctrl = make_controller("cascaded", hand)
    dist = ctrl.GetSubsystemByName("force_stage").GetSubsystemByName("force_distribution")
    assert dist._batch is not None                            # the compiled path serves the mixed hand
    f = np.linspace(10.0, 120.0, 38)
    k_law = springs.stiffness(springs.inverse_force(f))
    k_table = np.concatenate([s.stiffness_map(f[st])[0] for s, _, st, _, _ in dist._parts])
    np.testing.assert_allclose(k_table, k_law, rtol=1e-6)
    law = ctrl.GetSubsystemByName("force_stage").GetSubsystemByName("tendon_force_control").law
    r_m = hand.params.motor.pulley_radius
    np.testing.assert_allclose([fm.alpha_of_force(fi) for fm, fi in zip(law.fmaps, f)], r_m * k_law, rtol=1e-6)
    assert abs(k_law[over[0]] / _k_of_force(springs[0], f[over[0]]) - 1.0) > 0.02   # the overrides differ


def test_the_drive_evaluates_each_tendons_law():
    """The finger with one law overridden (ideal drive) has the state derivatives of the laws evaluated apart
    (each tendon's own spring law, the routing, the MultibodyPlant, (3.5)) off the operating point, and they differ
    from the finger with one law for all."""
    base = FingerRigParams.for_finger("index").with_physics(hysteresis=False, guide_friction=False)
    p = base.replace(tendon_springs=(("index_h3", base.spring.replace(tendon=STIFF)),))
    derivs = []
    for params in (p, base):
        rig = compiled(finger_diagram(finger="index", params=params))
        op = rig.operating_point(pretension=30.0)
        ctx = rig.context(op)
        x = np.array(op.state, dtype=float)
        x[:4] += 0.05                                            # joints off the equilibrium: the springs work
        ctx.SetContinuousState(x)
        derivs.append(rig.diagram.EvalTimeDerivatives(ctx).CopyToVector())
        n, m = rig.num_joints, rig.num_tendons
        ref = ideal_drive_derivatives(rig, x[:n], x[n:2 * n], x[2 * n:2 * n + m], x[2 * n + m:], op.motor_torque)
        np.testing.assert_allclose(derivs[-1], ref, rtol=0, atol=1e-9 * np.abs(ref).max())
    assert np.abs(derivs[1] - derivs[0]).max() > 1e-6 * np.abs(derivs[0]).max()
