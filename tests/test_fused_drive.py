"""The fused tendon drive: compiled float kernel = the law functions, scalar conversion,
lean ports, and the one-system single-joint rigs against their laws written out apart."""

import itertools

import numpy as np
import pytest
from pydrake.systems.controllers import LinearQuadraticRegulator
from pydrake.systems.framework import DiagramBuilder

from awiwi_drake.components import ConstantCoupling, antagonistic_coupling, tendon_spring
from awiwi_drake.components.fused_drive import DriveModel, GuideFrictionModel, build_kernels, drive_laws
from awiwi_drake.components.spring import PolynomialSpring
from awiwi_drake.hand.coupling import finger_coupling
from awiwi_drake.parameters import HysteresisParams, MotorParams, SpringModelParams
from awiwi_drake.parameters.components import GuideFrictionParams
from awiwi_drake.rigs import flexible_joint_rig, joint_rig, tendon_rig
from _fd import check_system_autodiff_matches_fd, fd_jacobian
from _joint_rig_check import rig_law_derivatives

RNG = np.random.default_rng(7)
SPRING = tendon_spring(SpringModelParams())
SOFT = PolynomialSpring((1.5e4, 2.0e6))          # a second law for per-tendon springs


def _thumb_model(*, friction, ripple, hysteresis, guide, capstan, per_tendon, rate_joints=None):
    c = finger_coupling("thumb")
    m = c.num_tendons
    springs = tuple(SOFT if (per_tendon and i % 3 == 0) else SPRING for i in range(m))
    gf = GuideFrictionModel(tuple(np.linspace(0.5, 3.0, m)), GuideFrictionParams(), capstan=capstan) if guide else None
    return DriveModel(MotorParams(friction=friction, ripple=ripple), springs, c, np.full(m, 2e-3), 0.005,
                      HysteresisParams(enabled=hysteresis), gf, rate_joints)


def _random_state(model):
    s = RNG.normal(size=model.num_states)
    _, _, th, om, z, g = model.split_state(s)
    th[:] = RNG.uniform(-0.3, 1.3, size=th.size)       # slack, inside and beyond the calibrated range
    om[:] = RNG.normal(scale=3.0, size=om.size)
    if z is not None:
        z[:] = RNG.normal(scale=5.0, size=z.size)
    if g is not None:
        g[:] = RNG.normal(scale=2.0, size=g.size)
    return s


SWITCHES = list(itertools.product([False, True], repeat=5))   # friction, ripple, hysteresis, guide, per-tendon


@pytest.mark.parametrize("friction,ripple,hysteresis,guide,per_tendon", SWITCHES)
def test_kernel_equals_laws_at_random_states_thumb(friction, ripple, hysteresis, guide, per_tendon):
    model = _thumb_model(friction=friction, ripple=ripple, hysteresis=hysteresis, guide=guide,
                         capstan=per_tendon, per_tendon=per_tendon)   # capstan rides on per_tendon: both forms covered
    # all switches on / all off: the numba-compiled kernel; the others: the same generated source
    # as plain Python (numba's compile time per variant would dominate the suite)
    switches = (friction, ripple, hysteresis, guide, per_tendon)
    k = build_kernels(model, jit=all(switches) or not any(switches))
    n, m = model.num_joints, model.num_tendons
    for _ in range(4):
        s = _random_state(model)
        u = RNG.normal(scale=4.0, size=m)                      # beyond the 3 Nm limit too
        q, qd = RNG.normal(scale=0.5, size=n), RNG.normal(scale=2.0, size=n)
        ref = drive_laws(model, s, u, q, qd if model.needs_joint_velocity else None)
        got = dict(derivatives=k["derivatives"](s, u, q, qd, np.empty(model.num_states)),
                   tendon_force=k["tendon_force"](s, q, np.empty(m)),
                   tendon_stiffness=k["tendon_stiffness"](s, q, np.empty(m)),
                   elongation=k["elongation"](s, q, np.empty(m)),
                   generalized_force=k["generalized_force"](s, q, qd, np.empty(n)))
        for name, val in got.items():
            np.testing.assert_allclose(val, ref[name], rtol=1e-12, atol=1e-12 * max(1.0, np.max(np.abs(ref[name]))),
                                       err_msg=name)


def test_kernel_equals_laws_with_a_motor_and_a_hysteresis_loop_per_tendon():
    """The per-tendon forms a diagnosis writes back (FingerRigParams.tendon_motors / tendon_springs): one MotorParams
    and one HysteresisParams per tendon, loops off on some tendons and of other sizes on others; the generated
    kernel equals the law functions at random states, and a tendon without its loop keeps a zero loop force."""
    base = _thumb_model(friction=True, ripple=True, hysteresis=True, guide=True, capstan=True, per_tendon=True)
    m = base.num_tendons
    motors = tuple(MotorParams(friction=i % 2 == 0, ripple=i % 3 != 0, coulomb_torque=0.02 + 0.01 * i,
                               ripple_harmonics=(3.0, 0.01, -0.02) if i == 1 else ()) for i in range(m))
    loops = tuple(HysteresisParams(enabled=i not in (2, 5), width_ratio=0.05 + 0.02 * i, width_offset=0.1 * i,
                                   presliding_length=(1 + i) * 1e-4) for i in range(m))
    model = DriveModel(motors, base.springs, base.coupling, base.offsets, base.motor_pulley_radius, loops,
                       base.guide_friction)
    k = build_kernels(model, jit=False)               # the generated source (numba compiles the same source)
    n = model.num_joints
    for _ in range(4):
        s = _random_state(model)
        model.split_state(s)[4][[2, 5]] = 0.0          # the tendons without a loop start without loop force
        u = RNG.normal(scale=4.0, size=m)
        q, qd = RNG.normal(scale=0.5, size=n), RNG.normal(scale=2.0, size=n)
        ref = drive_laws(model, s, u, q, qd)
        got = k["derivatives"](s, u, q, qd, np.empty(model.num_states))
        np.testing.assert_allclose(got, ref["derivatives"], rtol=1e-12,
                                   atol=1e-12 * np.max(np.abs(ref["derivatives"])))
        np.testing.assert_allclose(k["tendon_force"](s, q, np.empty(m)), ref["tendon_force"], rtol=1e-12,
                                   atol=1e-12 * np.max(np.abs(ref["tendon_force"])))
        zdot = model.split_state(got)[4]
        assert np.all(zdot[[2, 5]] == 0.0) and np.all(zdot[[0, 1, 3, 4, 6, 7]] != 0.0)   # loops off / on


@pytest.mark.parametrize("hysteresis,guide", [(False, False), (True, True)])
def test_kernel_equals_laws_with_a_link_and_partial_rates(hysteresis, guide):
    rq = 0.008
    c = antagonistic_coupling(rq)
    gf = GuideFrictionModel((1.0, 2.5)) if guide else None
    model = DriveModel(MotorParams(ripple=True), (SPRING, SOFT), c, np.array([1e-3, 2e-3]), 0.005,
                       HysteresisParams(enabled=hysteresis), gf, link_inertia=(2e-4,), link_damping=(1e-3,))
    k = build_kernels(model)
    for _ in range(5):
        s = _random_state(model)
        u, e = RNG.normal(scale=4.0, size=2), RNG.normal(size=1)
        ref = drive_laws(model, s, u, tau_ext=e)
        np.testing.assert_allclose(k["derivatives"](s, u, e, np.empty(model.num_states)), ref["derivatives"],
                                   rtol=1e-12, atol=1e-12 * np.max(np.abs(ref["derivatives"])))
        np.testing.assert_allclose(k["generalized_force"](s, np.empty(1)), ref["generalized_force"], rtol=1e-12)
    # wrist-like quasi-static extra joints: only the first rate_joints velocities enter
    thumb = _thumb_model(friction=True, ripple=False, hysteresis=True, guide=True, capstan=False, per_tendon=False,
                         rate_joints=3)
    kt = build_kernels(thumb)
    s = _random_state(thumb)
    q, qd = RNG.normal(size=4), RNG.normal(size=3)
    u = RNG.normal(size=8)
    ref = drive_laws(thumb, s, u, q, qd)
    np.testing.assert_allclose(kt["derivatives"](s, u, q, qd, np.empty(thumb.num_states)), ref["derivatives"],
                               rtol=1e-12, atol=1e-12 * np.max(np.abs(ref["derivatives"])))


def test_drive_laws_autodiff_equals_finite_differences_on_the_thumb():
    """The drive's laws (posture-dependent P(q), hysteresis, guide friction with capstan, per-tendon springs,
    friction and ripple) in AutoDiffXd: the Jacobians of the state rates, tendon forces and generalised force
    w.r.t. state, motor torque, joint angle and joint velocity equal central differences of the float laws."""
    from pydrake.autodiffutils import ExtractGradient, InitializeAutoDiff
    model = _thumb_model(friction=True, ripple=True, hysteresis=True, guide=True, capstan=True, per_tendon=True)
    s = _random_state(model)
    s[8:16] *= 0.1   # moderate speeds keep the finite differences away from the tanh knees
    z0 = np.concatenate([s, RNG.normal(size=8), RNG.normal(scale=0.3, size=4), RNG.normal(scale=0.01, size=4)])
    k = model.num_states

    def laws(z):
        out = drive_laws(model, z[:k], z[k:k + 8], z[k + 8:k + 12], z[k + 12:])
        return np.concatenate([out["derivatives"], out["tendon_force"], out["generalized_force"]])
    J_ad = ExtractGradient(laws(InitializeAutoDiff(z0).ravel()))
    J_fd = fd_jacobian(laws, z0, h=1e-7)
    np.testing.assert_allclose(J_ad, J_fd, rtol=2e-5, atol=2e-5 * np.abs(J_fd).max())
    assert np.abs(J_ad[:, k + 8:]).max() > 0          # the joint inputs enter (P(q), the sliding rates)


def test_tendon_rig_outputs_are_the_laws_and_its_autodiff_matches_finite_differences():
    """The tendon rig (no joints: one SymbolicVectorSystem and the stateless outputs) with hysteresis: its forces,
    stiffness and applied torque equal drive_laws at random states; its AutoDiffXd conversion equals central
    differences of the float diagram for the time derivatives and every output."""
    from awiwi_drake.parameters import TendonRigParams
    p = TendonRigParams()
    rig = tendon_rig(params=p.replace(spring=p.spring.replace(hysteresis=HysteresisParams(enabled=True))))
    model, d = rig.drive.model, rig.diagram
    ctx = d.CreateDefaultContext()
    for _ in range(4):
        x = rig.operating_point().state + RNG.normal(scale=0.05, size=rig.num_states)
        u = RNG.normal(scale=2.0, size=1) * p.motor.torque_limit
        _set(rig, ctx, x, u)
        ref = drive_laws(model, x, u, np.zeros(0))
        for name in ("tendon_force", "tendon_stiffness", "applied_torque"):
            np.testing.assert_allclose(d.GetOutputPort(name).Eval(ctx), ref[name], rtol=1e-12, err_msg=name)
    x = rig.operating_point().state + RNG.normal(scale=0.01, size=rig.num_states)
    check_system_autodiff_matches_fd(d, x, dict(motor_torque=rig.operating_point().motor_torque), rtol=1e-5)


def test_non_compilable_spring_is_refused_with_its_name():
    from awiwi_drake.components.spring import LeverSpringMechanism
    model = DriveModel(MotorParams(), (LeverSpringMechanism(),), ConstantCoupling(np.zeros((1, 0))), np.zeros(1), 0.005)
    with pytest.raises(ValueError, match="LeverSpringMechanism"):
        build_kernels(model)
    with pytest.raises(ValueError, match="one spring law per tendon"):
        DriveModel(MotorParams(), (SPRING,), antagonistic_coupling(0.008), np.zeros(2), 0.005)


def test_kernels_are_traced_once_per_model_content():
    """Equal models (built apart, e.g. two diagrams or a clone) share one trace; any change re-traces."""
    def model(x0):
        return DriveModel(MotorParams(ripple=True), (SPRING, SOFT), antagonistic_coupling(0.008),
                          np.array([x0, 2e-3]), 0.005, link_inertia=(2e-4,), link_damping=(1e-3,))
    a, b, c = model(1e-3), model(1e-3), model(1.5e-3)
    ka = build_kernels(a, jit=False)
    assert build_kernels(b, jit=False) is ka
    kc = build_kernels(c, jit=False)
    assert kc is not ka
    s = np.array([0.05, 0.0, 0.3, 0.3, 0.0, 0.0])      # both tendons stretched
    for mdl, k in ((a, ka), (c, kc)):      # each kernel is its own model's laws
        np.testing.assert_allclose(k["tendon_force"](s, np.empty(2)), drive_laws(mdl, s)["tendon_force"], rtol=1e-12)
    assert not np.allclose(ka["tendon_force"](s, np.empty(2)), kc["tendon_force"](s, np.empty(2)))
    with pytest.raises(ValueError, match="read-only"):     # an in-place change would leave a stale kernel
        a.offsets[0] = 3e-3


def _set(rig, ctx, x, u, e=None):
    ctx.SetContinuousState(x)
    rig.diagram.GetInputPort("motor_torque").FixValue(ctx, u)
    if e is not None:
        rig.diagram.GetInputPort("external_torque").FixValue(ctx, e)


@pytest.mark.parametrize("build,kw", [(joint_rig, {}), (flexible_joint_rig, {"spring": "nonlinear"}),
                                      (flexible_joint_rig, {"spring": "linear"}), (tendon_rig, {})])
def test_rig_equals_its_laws_written_out_at_random_states(build, kw):
    """Each single-joint rig's state derivative equals its laws written out apart (spring law, (3.5), the link's
    I qdd = tau - d qd + tau_ext) at random states, to 1e-9."""
    rig = build(**kw)
    op = rig.operating_point()
    ctx = rig.context(op)
    for _ in range(5):
        x = op.state + RNG.normal(scale=0.05, size=op.state.size)
        u = op.motor_torque + RNG.normal(scale=0.5, size=op.motor_torque.size)
        e = RNG.normal(scale=0.05, size=1) if op.external_torque is not None else None
        _set(rig, ctx, x, u, e)
        ref = rig_law_derivatives(rig, x, u, e)
        np.testing.assert_allclose(rig.diagram.EvalTimeDerivatives(ctx).CopyToVector(), ref, rtol=1e-9,
                                   atol=1e-9 * np.max(np.abs(ref)))


def test_one_system_joint_rig_linearises_and_takes_lqr_in_a_composed_diagram():
    from awiwi_drake.analysis import linearize
    fast = joint_rig()
    op = fast.operating_point(pretension=25.0, joint_angle=0.2)
    la = linearize(fast, op)
    # Drake's Linearize (AutoDiffXd) = central differences of the laws written out
    A = fd_jacobian(lambda x: rig_law_derivatives(fast, x, op.motor_torque, [0.0]), op.state)
    B = fd_jacobian(lambda u: rig_law_derivatives(fast, op.state, u, [0.0]), op.motor_torque)
    np.testing.assert_allclose(la.A, A, rtol=1e-6, atol=1e-6 * np.max(np.abs(A)))
    np.testing.assert_allclose(la.B, B, rtol=1e-6, atol=1e-6 * np.max(np.abs(B)))
    # LQR on a diagram that contains the rig (composed, exported inputs)
    b = DiagramBuilder()
    r = b.AddSystem(fast.diagram)
    b.ExportInput(r.GetInputPort("motor_torque"), "u")
    b.ExportOutput(r.GetOutputPort("state"), "x")
    ext = b.ExportInput(r.GetInputPort("external_torque"), "ext")
    d = b.Build()
    ctx = d.CreateDefaultContext()
    ctx.SetContinuousState(op.state)
    d.get_input_port(0).FixValue(ctx, op.motor_torque)
    d.get_input_port(ext).FixValue(ctx, [0.0])
    Q, R = np.diag([100, 1, 1, 1, 0.01, 0.01]), np.eye(2)
    ctrl = LinearQuadraticRegulator(d, ctx, Q, R, input_port_index=0)
    K = -ctrl.D()
    closed = np.linalg.eigvals(la.A - la.B @ K)
    assert np.all(closed.real < 0)


def test_finger_per_tendon_spring_override_changes_only_that_tendon():
    from awiwi_drake.hand.diagrams import finger_diagram
    from awiwi_drake.parameters.hand import FingerRigParams
    from awiwi_drake.parameters.components import TendonParams
    base = FingerRigParams.for_finger("index")
    stiff_tendon = base.spring.replace(tendon=TendonParams(diameter=2.0e-3))   # 4x the section: stiffer in series
    p = base.replace(tendon_springs=(("index_h3", stiff_tendon),))
    rig, ref = finger_diagram(finger="index", params=p), finger_diagram(finger="index", params=base)
    names = rig.tendon_names
    i = names.index("index_h3")
    op, op_ref = rig.operating_point(pretension=30.0), ref.operating_point(pretension=30.0)
    k = rig.diagram.GetOutputPort("tendon_stiffness").Eval(rig.context(op))
    k_ref = ref.diagram.GetOutputPort("tendon_stiffness").Eval(ref.context(op_ref))
    others = [j for j in range(len(names)) if j != i]
    np.testing.assert_allclose(k[others], k_ref[others], rtol=1e-12)
    law = tendon_spring(stiff_tendon)
    assert k[i] == pytest.approx(float(law.stiffness(np.array([op.elongation[i]]))[0]), rel=1e-12)
    assert k[i] > k_ref[i]                       # a stiffer tendon in series stiffens the drive
    # both operating points hold the same forces: the override moved only that tendon's motor angle
    np.testing.assert_allclose(op.tendon_force, op_ref.tendon_force, rtol=1e-9)
    with pytest.raises(ValueError, match="unknown tendon 'x9'"):
        finger_diagram(finger="index", params=base.replace(tendon_springs=(("x9", stiff_tendon),)))
    # every tendon's stiffness is its own law's at its elongation
    laws = [tendon_spring(dict(p.tendon_springs).get(t, p.spring)) for t in names]
    np.testing.assert_allclose(k, [float(np.ravel(lw.stiffness(np.array([x])))[0]) for lw, x in zip(laws, op.elongation)],
                               rtol=1e-12)


def test_batched_joint_rigs_equal_the_single_rig_copy_by_copy():
    from awiwi_drake.rigs.batch import batched_joint_rig
    br = batched_joint_rig(5)
    rig = br.single
    ops = [rig.operating_point(pretension=f, joint_angle=a) for f, a in zip((10, 20, 30, 40, 50), (0, .1, -.1, .2, 0))]
    ctx = br.context(ops)
    x = ctx.get_continuous_state_vector().CopyToVector() + RNG.normal(scale=0.01, size=30)
    ctx.SetContinuousState(x)
    d = br.diagram.EvalTimeDerivatives(ctx).CopyToVector()
    f = br.diagram.GetOutputPort("tendon_force").Eval(ctx)
    c1 = rig.context()
    for i, op in enumerate(ops):
        c1.SetContinuousState(x[6 * i:6 * i + 6])
        rig.diagram.GetInputPort("motor_torque").FixValue(c1, op.motor_torque)
        # round-off of the copy's own terms (an acceleration is a difference of u/B and r f/B terms ~1e2 1/s^2)
        np.testing.assert_allclose(d[6 * i:6 * i + 6], rig.diagram.EvalTimeDerivatives(c1).CopyToVector(), rtol=1e-12,
                                   atol=1e-12 * np.abs(d[6 * i:6 * i + 6]).max())
        np.testing.assert_allclose(f[2 * i:2 * i + 2], rig.diagram.GetOutputPort("tendon_force").Eval(c1), rtol=1e-12)
    # the batch converts too (law path per copy): its AutoDiffXd derivatives equal central differences of the
    # float (compiled) batch, for the time derivatives and every output, w.r.t. state and both inputs
    check_system_autodiff_matches_fd(br.diagram, x, dict(motor_torque=np.concatenate([op.motor_torque for op in ops]),
                                                         external_torque=RNG.normal(scale=0.01, size=5)), rtol=1e-5)


def test_hysteresis_loop_width_equals_the_dahl_closed_form():
    """A spring stretched back and forth far beyond the presliding range: the loaded and unloaded
    branches at the same elongation differ by the Dahl width of :func:`hysteresis_rate` (Fig 4.8b loop).

    With a constant half-width w (beta = 0) the loop has a closed form: on a cycle of amplitude A
    the state swings between +-Z, Z = w tanh(A / delta), and at the centre of the cycle the loading
    branch carries z = w - (w + Z) exp(-A / delta): the width is twice that.  The law's state is integrated
    along the prescribed elongation x(t) = x0 + A sin(2 pi f t) by scipy's DOP853 (an independent integrator)."""
    from scipy.integrate import solve_ivp

    from awiwi_drake.components.spring import hysteresis_rate
    hyst = HysteresisParams(enabled=True, width_ratio=0.0, width_offset=4.5)
    x0 = float(np.ravel(SPRING.inverse_force(np.array([40.0])))[0])
    amp, freq = 1e-3, 4.0
    w0 = 2 * np.pi * freq

    def elongation(t):
        return x0 + amp * np.sin(w0 * t), amp * w0 * np.cos(w0 * t)

    def rate(t, z):
        x, xdot = elongation(t)
        return np.ravel(hysteresis_rate(z, np.array([x]), np.array([xdot]), SPRING.force(np.array([x])), hyst))
    t = np.linspace(0.35, 0.6, 20001)                    # one full cycle after the first loading
    sol = solve_ivp(rate, (0.0, 0.6), [0.0], method="DOP853", rtol=1e-10, atol=1e-12, t_eval=t)
    x, xdot = elongation(t)
    f = np.ravel(SPRING.force(x)) + sol.y[0]
    centre, A = 0.5 * (x.max() + x.min()), 0.5 * (x.max() - x.min())
    widths = []
    for sign in (1, -1):
        sel = sign * xdot > 0
        order = np.argsort(x[sel])
        widths.append(np.interp(centre, x[sel][order], f[sel][order]))
    w, delta = hyst.width_offset, hyst.presliding_length
    Z = w * np.tanh(A / delta)
    expected = 2 * (w - (w + Z) * np.exp(-A / delta))
    assert expected < 0.9 * 2 * w                   # not saturated: the presliding length shows
    # the direction tanh(xdot / v_s) departs from +-1 only within v_s = 1e-4 m/s of a reversal
    # (0.6 % of the peak rate 2 pi f A): bound 1 % of the width
    assert widths[0] - widths[1] == pytest.approx(expected, rel=0.01)


def _push_response_single(pretension):
    """Link angle 30 ms after a 0.5 N m motor-torque imbalance, one joint rig (fixed-step RK3)."""
    from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
    rig = joint_rig()
    op = rig.operating_point(pretension=pretension)
    ctx = rig.context(op)
    rig.diagram.GetInputPort("motor_torque").FixValue(ctx, op.motor_torque + [0.5, -0.5])
    sim = Simulator(rig.diagram, ctx)
    ResetIntegratorFromFlags(sim, "runge_kutta3", 1e-4)
    sim.get_mutable_integrator().set_fixed_step_mode(True)
    sim.AdvanceTo(0.03)
    return float(ctx.get_continuous_state_vector().CopyToVector()[0])


def _push_response_batch(points):
    """The same for every point at once: the copies of one batched rig."""
    from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
    from awiwi_drake.rigs.batch import batched_joint_rig
    br = batched_joint_rig(len(points))
    ops = [br.single.operating_point(pretension=p["pretension"]) for p in points]
    ctx = br.context(ops)
    _, u, _ = br.stack(ops)
    br.diagram.GetInputPort("motor_torque").FixValue(ctx, u + np.tile([0.5, -0.5], len(points)))
    sim = Simulator(br.diagram, ctx)
    ResetIntegratorFromFlags(sim, "runge_kutta3", 1e-4)
    sim.get_mutable_integrator().set_fixed_step_mode(True)
    sim.AdvanceTo(0.03)
    return list(ctx.get_continuous_state_vector().CopyToVector().reshape(len(points), 6)[:, 0])


def test_run_sweep_batch_gives_the_serial_numbers():
    from concurrent.futures import ThreadPoolExecutor
    from awiwi_drake.analysis import run_sweep
    grid = {"pretension": [10.0, 20.0, 30.0, 40.0, 50.0]}
    serial = run_sweep(_push_response_single, grid, executor="serial", quiet=True)
    batched = run_sweep(_push_response_batch, grid, executor="serial", batch=2, quiet=True)
    with ThreadPoolExecutor(2) as ex:
        threaded = run_sweep(_push_response_batch, grid, executor=ex, batch=3, quiet=True)
    # fixed-step RK3 acts element-wise on the stacked state: the copies reproduce the single runs
    np.testing.assert_allclose(batched.values, serial.values, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(threaded.values, serial.values, rtol=1e-12, atol=1e-15)
    assert len(set(np.round(serial.values, 9))) == 5     # the pretension matters (stiffer joint, smaller push)
    with pytest.raises(ValueError, match="batch = 0"):
        run_sweep(_push_response_batch, grid, executor="serial", batch=0)


def test_drive_stiffness_is_the_lever_in_series_with_the_tendon():
    """Tendon elasticity k_t = E S / l0 in series with the lever mechanism (ch. 4): the compiled joint rig's
    tendon_stiffness at a pretension equals (1/k_lever(f) + 1/k_t)^-1 at that force, to the calibration
    polynomial's accuracy (1 %; the tendon halves the stiffness at high force, so the check has teeth)."""
    from awiwi_drake.components.spring import LeverSpringMechanism
    from awiwi_drake.components.tendon import series_stiffness, tendon_stiffness
    rig = joint_rig()
    sp = rig.params.spring
    assert sp.include_tendon
    lever, k_t = LeverSpringMechanism(sp.geometry), tendon_stiffness(sp.tendon)
    for f in (10.0, 40.0, 80.0, 150.0):
        op = rig.operating_point(pretension=f)
        k = rig.diagram.GetOutputPort("tendon_stiffness").Eval(rig.context(op))
        k_lever = float(np.ravel(lever.stiffness(np.atleast_1d(lever.inverse_force(np.array([f])))))[0])
        expected = float(series_stiffness(k_lever, k_t))
        np.testing.assert_allclose(k, expected, rtol=0.01)
        if f >= 80.0:
            assert k_lever > 1.3 * expected          # without the tendon: >= 30 % off (1 % tolerance)
