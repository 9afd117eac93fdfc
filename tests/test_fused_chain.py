"""The fused chain (control/fused.py): the hand's estimator -> joint stage -> distribution -> force law as one
discrete system equals the composed blocks (closed_loop(fused=False)) to round-off, period by period, for every
registered controller that reads the estimated joint state; it converts to AutoDiffXd and its sampled
linearisation is the composed loop's."""

import numpy as np
import pytest
from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, ExtractValue, InitializeAutoDiff

from _fd import fd_jacobian
from awiwi_drake.analysis import simulate
from awiwi_drake.components.friction import joint_breakaway_bound
from awiwi_drake.control import closed_loop, controller_names, get_entry, make_controller
from awiwi_drake.control.fused import FusedChain_
from awiwi_drake.control.joint_design import sampled_loop_poles
from awiwi_drake.hand.diagrams import finger_diagram, hand_diagram
from awiwi_drake.parameters.hand import FingerRigParams

PERIOD = 1.0 / 3000.0
#: every controller registered for fingers/the hand that reads the estimated joint state (joint-pd does not)
ESTIMATED = ("cascaded", "pd", "two-time-scale", "pole-placement", "lqr", "sdre", "backstepping",
             "backstepping-position", "backstepping-nonlinear-spring", "optimal-backstepping")
LOGS = ("motor_torque", "motor_torque_command", "joint_angle_estimate", "joint_velocity_estimate",
        "joint_angle_estimation_error", "joint_angle", "tendon_force")


def _rig(target):
    if target == "finger-thumb-capstan":           # tension-proportional guide friction: W depends on the force
        return finger_diagram(finger="thumb", params=FingerRigParams.for_finger("thumb").replace(capstan_friction=True))
    return hand_diagram() if target == "hand" else finger_diagram(finger=target.removeprefix("finger-"))


def _random_start(rig, seed):
    """A random state near the operating point (joints, their velocities, motor angles) and a random reference."""
    rng = np.random.default_rng(seed)
    op = rig.operating_point()
    x = np.array(op.state, dtype=float)
    n, m = rig.num_joints, rig.num_tendons
    x[:n] += rng.uniform(-0.05, 0.05, n)
    x[n:2 * n] += rng.uniform(-0.3, 0.3, n)
    x[2 * n:2 * n + m] += rng.uniform(-2e-3, 2e-3, m)
    return op, x, op.joint_angle + rng.uniform(-0.1, 0.1, n)


def _run(target, name, fused, seed, periods=8):
    rig = _rig(target)
    loop = closed_loop(rig, make_controller(name, rig), fused=fused, **get_entry(name, rig).loop_options)
    op, x, ref = _random_start(rig, seed)
    ctx = loop.create_context(op, state=x, references={"joint_angle_reference": ref})
    logs = LOGS + tuple(p for p in ("controller_tendon_force_reference", "controller_joint_torque_reference",
                                    "controller_distribution_status") if loop.diagram.HasOutputPort(p))
    return loop, simulate(loop, ctx, periods / loop.rate_hz, log=logs)


def _assert_same(a, b):
    assert a.signals.keys() == b.signals.keys()
    np.testing.assert_array_equal(a.t, b.t)
    for k in a.signals:
        scale = max(1.0, float(np.max(np.abs(a[k]))))
        np.testing.assert_allclose(b[k], a[k], rtol=0, atol=1e-12 * scale, err_msg=k)


@pytest.mark.filterwarnings("ignore:sdre. measured joint torque deviation")   # the random start leaves its table
@pytest.mark.parametrize("name", ESTIMATED)
def test_fused_equals_composed_on_the_thumb(name):
    """The thumb: P(q) and Algorithm 1 in every stage; every registered controller reading the estimates."""
    assert name in controller_names("finger-thumb")
    composed, a = _run("finger-thumb", name, False, seed=1)
    fused, b = _run("finger-thumb", name, True, seed=1)
    assert composed.fused is None and composed.diagram.HasSubsystemNamed("estimator")
    assert isinstance(fused.fused, FusedChain_[float]) and not fused.diagram.HasSubsystemNamed("estimator")
    assert fused.diagram.GetSubsystemByName("controller") is fused.fused
    _assert_same(a, b)
    # the loop moved: the comparison is not of two constant traces
    assert np.ptp(a["motor_torque"], axis=0).max() > 1e-3


@pytest.mark.parametrize("name", ["cascaded", "lqr", "backstepping"])
def test_fused_equals_composed_on_the_hand(name):
    """The hand (five fingers, one distribution batch, the thumb's kernels, the wrist offsets)."""
    _, a = _run("hand", name, False, seed=2, periods=6)
    loop, b = _run("hand", name, True, seed=2, periods=6)
    assert loop.fused is not None and np.ptp(a["motor_torque"], axis=0).max() > 1e-3   # fused, and the loop moved
    _assert_same(a, b)


def test_fused_chain_on_a_ring_finger_with_coupled_dip():
    """The ring: DoF selection S (the DIP follows the PIP, (5.16)) in the estimator, the stage and the distribution."""
    _, a = _run("finger-ring", "cascaded", False, seed=3)
    loop, b = _run("finger-ring", "cascaded", True, seed=3)
    assert loop.fused is not None and np.ptp(a["motor_torque"], axis=0).max() > 1e-3   # fused, and the loop moved
    _assert_same(a, b)


def test_fused_is_not_used_where_the_blocks_must_stay():
    """Ideal sensors, a sensor model or a continuous controller state (the ch. 9 observer of a continuous chain,
    ``distribution="sharing"``) keep the blocks; the sampled observer (the default) is fused."""
    from awiwi_drake.control.joint_design import joint_stage_controller
    rig = _rig("finger-index")
    assert closed_loop(rig, make_controller("cascaded", rig), sensors="ideal").fused is None
    rig = _rig("finger-index")
    assert closed_loop(rig, joint_stage_controller(rig, "cascaded", distribution="sharing")).fused is None
    rig = _rig("finger-index")
    assert closed_loop(rig, joint_stage_controller(rig, "cascaded")).fused is not None
    rig = _rig("finger-index")
    assert closed_loop(rig, make_controller("joint-pd", rig)).fused is None      # no estimates read


def _autodiff_output(loop, ctx, output, ref_port="joint_angle_reference"):
    """An output of the loop in AutoDiffXd w.r.t. the reference: (value, gradient)."""
    d = loop.diagram
    ad = d.ToAutoDiffXd()
    actx = ad.CreateDefaultContext()
    actx.SetTimeStateAndParametersFrom(ctx)
    ref = np.asarray(d.GetInputPort(ref_port).Eval(ctx), dtype=float)
    xa = InitializeAutoDiff(ref).ravel()
    for i in range(d.num_input_ports()):
        port = d.get_input_port(i)
        if port.get_name() == ref_port:
            ad.get_input_port(i).FixValue(actx, xa)
        elif port.HasValue(ctx):
            ad.get_input_port(i).FixValue(actx, np.array([AutoDiffXd(v) for v in port.Eval(ctx)], dtype=object))
    u = ad.GetOutputPort(output).Eval(actx)
    return ExtractValue(u).ravel(), ExtractGradient(u)


@pytest.mark.parametrize("name, output", [("cascaded", "controller_joint_torque_reference"),
                                          ("backstepping", "motor_torque_command")])
def test_fused_converts_to_autodiff_and_its_derivative_is_the_composed_one(name, output):
    """ToAutoDiffXd of the fused loop: an output's value equals the float one, and its derivative by the reference
    equals the composed loop's AutoDiffXd derivative and central finite differences of the float loop (the chain's
    command reads the distribution's previous answer, so its reference path is the joint stage's torque)."""
    rig = _rig("finger-thumb")
    fused = closed_loop(rig, make_controller(name, rig), **get_entry(name, rig).loop_options)
    rig2 = _rig("finger-thumb")
    composed = closed_loop(rig2, make_controller(name, rig2), fused=False, **get_entry(name, rig2).loop_options)
    op, x, ref = _random_start(rig, 4)
    cf = fused.create_context(op, state=x, references={"joint_angle_reference": ref})
    cc = composed.create_context(op, state=x, references={"joint_angle_reference": ref})
    assert FusedChain_[AutoDiffXd] is not None and fused.fused.ToAutoDiffXd() is not None
    uf, Gf = _autodiff_output(fused, cf, output)
    uc, Gc = _autodiff_output(composed, cc, output)
    u0 = fused.diagram.GetOutputPort(output).Eval(cf)
    np.testing.assert_allclose(uf, u0, rtol=0, atol=1e-12 * max(1, np.abs(u0).max()))
    np.testing.assert_allclose(Gf, Gc, rtol=1e-10, atol=1e-10 * max(1.0, np.abs(Gc).max()))
    port = fused.diagram.GetInputPort("joint_angle_reference")

    def output_at(r):
        port.FixValue(cf, r)
        return fused.diagram.GetOutputPort(output).Eval(cf).copy()
    fd = fd_jacobian(output_at, ref, h=1e-6)
    assert np.abs(Gf).max() > 0        # the reference moves the command (the test can fail)
    np.testing.assert_allclose(Gf, fd, rtol=1e-5, atol=1e-5 * np.abs(fd).max())


@pytest.mark.parametrize("name", ["cascaded", "lqr"])
def test_sampled_linearisation_of_the_fused_loop_is_the_composed_one(name):
    """sampled_loop_poles (the one-period map's AutoDiffXd Jacobian, estimator and distribution states included)
    through the fused system equals the composed blocks' (index, guide friction and hysteresis on)."""
    rig = _rig("finger-index")
    pf = sampled_loop_poles(rig, make_controller(name, rig))
    rig = _rig("finger-index")
    pc = sampled_loop_poles(rig, make_controller(name, rig), fused=False)
    assert pf.jacobian.shape == pc.jacobian.shape
    scale = np.abs(pc.jacobian).max()
    # the state groups are ordered differently (rig, then the controller's states in its own order): compare the
    # spectra and the reference-to-joint-angle response, which do not depend on the order
    np.testing.assert_allclose(np.sort_complex(pf.z), np.sort_complex(pc.z), rtol=0, atol=1e-9 * max(1.0, scale))
    _, yf = pf.step_response(np.full(rig.num_joints, 0.01), 0.01)
    _, yc = pc.step_response(np.full(rig.num_joints, 0.01), 0.01)
    np.testing.assert_allclose(yf, yc, rtol=0, atol=1e-12)
    assert pf.spectral_radius == pytest.approx(pc.spectral_radius, rel=1e-9)


def test_compiled_force_law_equals_the_law_as_written():
    """TendonForceLaw's float bank path (one compiled call, control/compiled.py) equals the law as written
    (TendonForceLaw.evaluate) to round-off: fixed and scheduled gains, one map for all tendons and a map per tendon,
    friction and ripple feed-forward, tendon path velocity, readings off the table's ends; a bad reference raises
    naming its tendon, as the law does."""
    from awiwi_drake.components.spring import tendon_spring
    from awiwi_drake.control.tendon_force import ForceMap, TendonForceLaw
    from awiwi_drake.parameters.components import MotorParams, TendonParams
    from awiwi_drake.parameters.control import TendonForceGains
    from awiwi_drake.parameters.hand import FingerDriveParams
    nominal = FingerDriveParams().spring
    motor = MotorParams(ripple=True)
    maps = [ForceMap.from_spring(tendon_spring(s), motor.pulley_radius)
            for s in (nominal, nominal.replace(tendon=TendonParams(diameter=2.0e-3)))]
    m = 12
    rng = np.random.default_rng(7)
    top = min(fm.max_force for fm in maps)
    u = {"tendon_force_reference": np.concatenate([[0.0, top], rng.uniform(0.0, 150.0, m - 2)]),
         "tendon_force": np.concatenate([[-3.0, 260.0], rng.uniform(0.0, 150.0, m - 2)]),
         "motor_velocity": rng.normal(0, 5, m), "motor_angle": rng.uniform(-3, 3, m),
         "tendon_path_velocity": rng.normal(0, 0.01, m)}
    for fmap in (maps[0], [maps[i % 2] for i in range(m)]):
        for scheduled in (False, True):
            law = TendonForceLaw(fmap, motor, TendonForceGains(friction_scale=0.7), size=m, scheduled=scheduled,
                                 ripple_scale=0.8, path_velocity=True)
            fast, ref = law(u), law.evaluate(u)
            assert law.__dict__.get("_kernel") is not None           # the compiled path ran
            np.testing.assert_allclose(fast, ref, rtol=1e-13, atol=1e-12)
    bad = dict(u, tendon_force_reference=np.where(np.arange(m) == 5, np.nan, u["tendon_force_reference"]))
    with pytest.raises(ValueError, match=r"tendon_force_reference\[5\] = nan"):
        law(bad)


@pytest.mark.parametrize("target, name", [("hand", "backstepping"), ("finger-thumb", "backstepping"),
                                          ("hand", "backstepping-friction-observer"),
                                          ("finger-thumb", "backstepping-friction-observer"),
                                          ("finger-thumb-capstan", "backstepping-friction-observer"),
                                          ("finger-thumb", "backstepping-load-observer")])
def test_compiled_backstepping_equals_the_law_as_written(target, name):
    """The 15.5 law's float path (one compiled call, polynomial springs) equals FingerBacksteppingLaw.terms (the law
    for every scalar type) at random measurements: relative 1e-12 of the command; with the link torque estimate and its
    compensation bounded by the frictions (``backstepping-friction-observer``) at estimates inside and beyond the
    bound (half of the DoF each; with the capstan guide law the bound's levels depend on the forces,
    :func:`~awiwi_drake.components.friction.joint_friction_bound`, and there the joints' breakaway levels, random per
    joint, join the bound through ``|S|^T Fs``); with the estimate in the link model alone
    (``backstepping-load-observer``)."""
    rig = _rig(target)
    law = make_controller(name, rig).law
    op = rig.operating_point()
    rng = np.random.default_rng(8)
    if target == "finger-thumb-capstan":           # joint levels as a plant with stick-slip joints gives them
        law.friction_levels = (*law.friction_levels[:2],
                               joint_breakaway_bound(rng.uniform(0.005, 0.03, op.joint_angle.size), law.S))
    loop = closed_loop(rig, make_controller("backstepping", rig))           # the measurements' values only
    ctx = loop.create_context(op)
    plant = loop.diagram.GetSubsystemByName("rig")
    pctx = plant.GetMyContextFromRoot(ctx)
    n = op.joint_angle.size
    for _ in range(4):
        u = {nm: plant.GetOutputPort(nm).Eval(pctx) + rng.normal(scale=s, size=plant.GetOutputPort(nm).size())
             for nm, s in (("elongation", 2e-4), ("motor_angle", 0.1), ("motor_velocity", 1.0))}
        u.update(joint_angle=op.joint_angle + rng.normal(scale=0.05, size=n), joint_velocity=rng.normal(scale=0.3, size=n),
                 joint_angle_reference=op.joint_angle + rng.normal(scale=0.1, size=n))
        if law.link_torque_estimate:
            B = law.friction_bound(law.f_op)
            u["friction_compensation"] = B * rng.uniform(-1, 1, B.size) * np.where(np.arange(B.size) % 2, 3.0, 0.5)
        ref, fast = law.terms(u)["command"], law(u)
        assert law._fast                                          # the compiled path ran
        if law.link_torque_estimate:                              # the estimate enters both paths
            assert np.abs(law({**u, "friction_compensation": 0 * u["friction_compensation"]}) - fast).max() > 0
        np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-12 * np.abs(ref).max())


def test_compiled_joint_feedback_equals_the_law_as_written():
    """JointStateFeedbackLaw's float path for the PD / impedance form (one compiled call) equals the law as written
    (the path every other scalar type takes: here the same call on AutoDiffXd inputs, whose values are compared) on
    the hand's cascaded design."""
    rig = _rig("hand")
    law = make_controller("cascaded", rig)._joint_law
    assert not law.uses_forces and not law.uses_previous
    rng = np.random.default_rng(9)
    n = rig.num_joints
    for _ in range(3):
        u = dict(joint_angle=rng.normal(scale=0.3, size=n), joint_velocity=rng.normal(size=n),
                 joint_angle_reference=rng.normal(scale=0.3, size=n))
        ua = {k: np.array([AutoDiffXd(x) for x in v], dtype=object) for k, v in u.items()}
        ref = ExtractValue(law(ua)).ravel()                        # the law as written (not the compiled call)
        assert np.abs(ref).max() > 0
        np.testing.assert_allclose(law(u), ref, rtol=0, atol=1e-13 * np.abs(ref).max())


def test_compiled_table_lookup_of_the_distribution_equals_numpy_interp():
    """The (7.6) batch's per-tendon stiffness look-up (bisection written out) equals numpy.interp bit for bit: inside,
    on grid points, at and beyond both ends."""
    from awiwi_drake.control.force_distribution import _interp_rows
    rng = np.random.default_rng(10)
    gf = np.sort(rng.uniform(0.0, 200.0, (8, 500)), axis=1)
    gv = rng.normal(size=(8, 500))
    for trial in range(50):
        f = rng.uniform(-10.0, 210.0, 8)
        if trial == 0:
            f[:4] = gf[0, 0], gf[1, -1], gf[2, 17], gf[3, 0] - 1.0
        np.testing.assert_array_equal(_interp_rows(f, gf, gv), [np.interp(f[i], gf[i], gv[i]) for i in range(8)])


def test_initialize_controller_without_joint_angles_keeps_the_estimate_as_the_composed_loop_does():
    """``ClosedLoop.initialize_controller(context)`` with no pose (its default) restarts the distribution and the
    friction observer and keeps the estimator's state, fused or composed (it raised ``TypeError: object of type
    'NoneType' has no len()`` on a fused loop): after it both loops run the same periods to round-off."""
    runs = []
    for fused in (False, True):
        rig = _rig("finger-index")
        loop = closed_loop(rig, make_controller("cascaded", rig), fused=fused, **get_entry("cascaded", rig).loop_options)
        op, x, ref = _random_start(rig, seed=4)
        ctx = loop.create_context(op, state=x, references={"joint_angle_reference": ref})
        loop.initialize_controller(ctx)
        assert (loop.fused is not None) == fused
        if fused:      # the estimate and its velocity filter are kept (create_context started them at the pose)
            own = loop.fused.GetMyContextFromRoot(ctx)
            for group in (loop.fused._xq, loop.fused._xz):
                np.testing.assert_array_equal(own.get_discrete_state(group).CopyToVector(), rig.joint_angles_of(x))
        runs.append(simulate(loop, ctx, 6 / loop.rate_hz, log=LOGS))
    _assert_same(*runs)
