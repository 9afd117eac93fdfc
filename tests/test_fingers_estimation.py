"""Link-position estimation: pseudo-inverse (5.15), Algorithm 1 (Fig 5.16-5.17)."""

from __future__ import annotations

import numpy as np
import pytest

from awiwi_drake.hand.coupling import finger_coupling
from awiwi_drake.hand.estimation import estimate_linear, estimate_thumb, noise_error_bound, thumb_base_gradient_search
from awiwi_drake.reproductions.ch05_fingers import thumb_estimation_study
from awiwi_drake.parameters.hand import finger_params
from awiwi_drake.parameters.hand_control import LinkEstimatorParams


@pytest.mark.parametrize("finger", ["index", "middle", "ring", "fifth"])
def test_pseudo_inverse_recovers_joint_angles(finger):
    c = finger_coupling(finger)
    rng = np.random.default_rng(3)
    q_dof = rng.uniform(-1, 1, c.dof_selection.shape[1])
    q = c.dof_selection @ q_dof          # ring/fifth: DIP follows PIP (5.16)
    np.testing.assert_allclose(estimate_linear(c, c.h(q) - c.h(np.zeros_like(q))), q, atol=1e-14)
    # least squares: noise e moves the estimate by pinv(P S) e exactly (linear problem)
    e = rng.uniform(-1e-3, 1e-3, c.num_tendons)
    dq = estimate_linear(c, c.h(q) - c.h(np.zeros_like(q)) + e) - q
    sigma_min = np.linalg.svd(c.P() @ c.dof_selection, compute_uv=False)[-1]
    assert np.linalg.norm(dq) <= np.linalg.norm(e) / sigma_min + 1e-15


def test_ring_dip_follows_5_16():
    p = finger_params("ring")
    c = finger_coupling("ring", p)
    q = np.array([0.1, 0.4, 0.8, 0.8 * p.dip_radius / p.pip_radius])
    est = estimate_linear(c, c.h(q))
    assert est[3] / est[2] == pytest.approx(p.dip_radius / p.pip_radius)


def test_gradient_search_converges_noise_free_cold_start():
    c = finger_coupling("thumb")
    q_true = np.array([0.9, -0.6, 0.0, 0.0])
    dh = c.h(q_true)[:4] - c.h(np.zeros(4))[:4]
    r = thumb_base_gradient_search(c, dh, (0.0, 0.0), iterations=50)
    np.testing.assert_allclose(r.q, q_true[:2], atol=1e-5)
    # 15 iterations of 0.1 rad cannot reach a corner 2.1 rad away from a cold start (Fig 5.17 g-i)
    far = np.array([1.5, 1.5, 0, 0])
    r15 = thumb_base_gradient_search(c, c.h(far)[:4] - c.h(np.zeros(4))[:4], (0.0, 0.0), iterations=15)
    assert np.linalg.norm(r15.q - far[:2]) > 0.3


def test_full_thumb_estimate():
    c = finger_coupling("thumb")
    q = np.array([0.3, 0.2, 0.5, -0.4])
    np.testing.assert_allclose(estimate_thumb(c, c.h(q) - c.h(np.zeros(4)), iterations=50), q, atol=1e-5)


def test_warm_start_with_1mm_noise_stays_within_the_noise_propagation_bound():
    """Fig 5.16-5.17, warm start, 1 mm noise: |q_hat - q| <= 2 a / sigma_min(P(q)) + 2 step_final.

    Derivation: at the least-squares optimum of the noisy problem, to first
    order dq = P^+ e with |e| <= 2 a (4 tendons, |e_i| <= a), so
    |dq| <= 2 a / sigma_min(P); the fixed-step search stops within about two
    final steps of that optimum.  A 20 % margin covers the second-order term.
    """
    c = finger_coupling("thumb")
    study = thumb_estimation_study(c, n_grid=9, iterations=(30,), noise=(1e-3,), starts=("warm",))
    err = study.errors[(30, 1e-3, "warm")]
    bound = study.bounds[(30, 1e-3, "warm")]
    assert np.all(err <= 1.2 * bound), float(np.max(err / bound))
    # the bound is meaningful (tens of mrad in the middle of the workspace, not radians)
    assert noise_error_bound(c, (0.0, 0.0), 1e-3) < 0.05
    assert np.median(err) < 0.03


def test_estimation_rejects_bad_shapes():
    c = finger_coupling("thumb")
    with pytest.raises(ValueError, match="dh_base"):
        thumb_base_gradient_search(c, np.zeros(3))
    with pytest.raises(ValueError, match="dh"):
        estimate_linear(finger_coupling("index"), np.zeros(5))


def test_estimator_system_converts_and_its_derivative_is_the_pseudo_inverse():
    from pydrake.autodiffutils import ExtractGradient, ExtractValue, InitializeAutoDiff
    from awiwi_drake.hand.estimation import LinkPositionEstimator
    c = finger_coupling("thumb")
    est = LinkPositionEstimator(c, 0.005, np.full(8, 1e-3), iterations=50)
    ad = est.ToAutoDiffXd()
    q = np.array([0.4, -0.3, 0.2, 0.1])
    theta = np.linspace(-1, 1, 8)
    x = 0.005 * theta + c.h(q) - c.h(np.zeros(4)) + 1e-3
    ctx = ad.CreateDefaultContext()
    ctx.SetDiscreteState(q + 0.01)                          # warm start near the truth
    ad.GetInputPort("motor_angle").FixValue(ctx, theta)
    ad.GetInputPort("elongation").FixValue(ctx, InitializeAutoDiff(x).ravel())
    nxt = ad.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector().CopyToVector()
    np.testing.assert_allclose(ExtractValue(nxt).ravel(), q, atol=1e-6)
    # d q_hat / d elongation = P(q)^+ (least squares on the 8 tendon lengths)
    np.testing.assert_allclose(ExtractGradient(nxt), np.linalg.pinv(c.P(q)), atol=1e-5)


def test_projection_onto_the_search_bound_is_reported_not_silent():
    """A pose beyond the +-pi/2 search bound: the estimate is the projection, and says so."""
    c = finger_coupling("thumb")
    h0 = c.h(np.zeros(4))[:4]
    inside = thumb_base_gradient_search(c, c.h(np.array([1.2, -0.4, 0, 0]))[:4] - h0, (1.1, -0.3), iterations=50)
    assert not inside.at_limit and inside.projected == 0
    beyond = np.array([1.8, 0.2, 0.0, 0.0])
    r = thumb_base_gradient_search(c, c.h(beyond)[:4] - h0, (1.5, 0.2), iterations=50)
    assert r.at_limit and r.projected > 0
    assert r.q[0] == pytest.approx(np.pi / 2) and r.limit == pytest.approx(np.pi / 2)
    # the study flags them per point and counts them per case: on a 3 x 3 grid the warm start jumps
    # 3 rad between neighbours and 15 iterations end on the bound at three corners
    study = thumb_estimation_study(c, n_grid=3, iterations=(15,), noise=(0.0,), starts=("warm",))
    key = (15, 0.0, "warm")
    on_bound = np.any(np.isclose(np.abs(study.estimates[key]), np.pi / 2), axis=1)
    np.testing.assert_array_equal(study.at_limit[key], on_bound)
    assert study.summary_rows()[0]["at_limit"] == 3
    assert np.all(study.errors[key][study.at_limit[key]] > 0.1)
    fig, axes = study.plot("warm")                          # Fig 5.17: one panel per case run, truth and estimate
    assert axes.shape == (1, 1)
    np.testing.assert_array_equal(axes[0, 0].get_lines()[1].get_xydata(), study.estimates[key])
    with pytest.raises(ValueError, match=r"case \(15, 0.0, 'cold'\) was not run"):
        study.plot(case=(15, 0.0, "cold"))
    import matplotlib.pyplot as plt
    plt.close(fig)
    # the 3 kHz estimator warns once and counts
    from awiwi_drake.hand.estimation import LinkPositionEstimator
    est = LinkPositionEstimator(c, 0.005, np.zeros(8), iterations=50)
    ctx = est.CreateDefaultContext()
    ctx.SetDiscreteState(beyond - [0.3, 0, 0, 0])
    est.GetInputPort("motor_angle").FixValue(ctx, np.zeros(8))
    est.GetInputPort("elongation").FixValue(ctx, c.h(beyond) - c.h(np.zeros(4)))
    with pytest.warns(RuntimeWarning, match="search bound"):
        est.EvalUniquePeriodicDiscreteUpdate(ctx)
    assert est.limit_hits == 1


def test_estimator_is_not_symbolic_and_says_so():
    """Algorithm 1 branches on cost values: float and AutoDiffXd only (T_list), a clear error otherwise."""
    from awiwi_drake.hand.estimation import LinkPositionEstimator
    est = LinkPositionEstimator(finger_coupling("thumb"), 0.005, np.zeros(8))
    est.ToAutoDiffXd()
    with pytest.raises(RuntimeError, match="LinkPositionEstimator_.*does not support scalar conversion.*Expression"):
        est.ToSymbolic()


def test_hand_estimator_float_update_equals_its_autodiff_values():
    """The float update refines finger by finger (P S is block-diagonal; the linear fingers' least squares
    is already exact), the AutoDiff one on the whole hand: the same estimate to 1e-12 rad."""
    from pydrake.autodiffutils import ExtractValue
    from awiwi_drake.hand.diagrams import hand_diagram
    rig = hand_diagram()
    lpe = rig.link_estimator().system.GetSubsystemByName("link_position_estimator")
    ad = lpe.ToAutoDiffXd()
    op = rig.operating_point()
    rng = np.random.default_rng(4)
    from awiwi_drake.hand.coupling import dof_selection
    S = dof_selection(rig.coupling)
    q = S @ rng.uniform(-0.2, 0.2, S.shape[1])            # a pose the coupled DIPs can take (5.16)
    theta = rng.uniform(-0.5, 0.5, rig.num_tendons)
    x = rig.params.motor.pulley_radius * theta + rig.coupling.h(q) - rig.coupling.h(np.zeros(q.size)) + rig.offsets
    noise = rng.normal(scale=1e-5, size=x.size)           # inconsistent lengths: a non-zero residual
    x = x + noise
    out = []
    for s in (lpe, ad):
        ctx = s.CreateDefaultContext()
        ctx.SetDiscreteState(q + 0.01)
        s.GetInputPort("motor_angle").FixValue(ctx, theta)
        s.GetInputPort("elongation").FixValue(ctx, x)
        s.GetInputPort("wrist_offset").FixValue(ctx, np.zeros(rig.num_tendons))
        out.append(np.asarray(ExtractValue(s.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector().CopyToVector()),
                              dtype=float).ravel())
    np.testing.assert_allclose(out[0], out[1], rtol=0, atol=1e-12)
    # least squares (5.15): the 10 um of length noise moves the estimate by S (P S)^+ noise (here ~5e-3 rad),
    # exactly for the constant-coupling fingers; the thumb's refinement converges quadratically from the
    # 0.01 rad start, so what remains beyond first order is far below 1e-6 rad
    PS = np.asarray(rig.coupling.P(q)) @ S
    predicted = S @ np.linalg.pinv(PS) @ noise
    assert np.abs(predicted).max() > 1e-3
    np.testing.assert_allclose(out[0] - q, predicted, rtol=0, atol=1e-6)


@pytest.mark.parametrize("refine", [False, True])
def test_hand_estimator_update_equals_the_law_functions(refine):
    """The float update (one block product for the constant-coupling fingers, the compiled Algorithm 1, the
    thumb's Gauss-Newton step on its 4 x 2 base block) equals the law functions finger by finger
    (estimate_linear (5.15), estimate_thumb, q + (P S)^+ r with numpy's pinv) to 1e-12 rad at random states."""
    from awiwi_drake.hand.diagrams import hand_diagram
    from awiwi_drake.hand.coupling import dof_selection
    from awiwi_drake.hand.estimation import link_state_estimator
    rig = hand_diagram()
    c = rig.coupling
    lpe = link_state_estimator(c, rig.params.motor.pulley_radius, rig.offsets, iterations=15,
                               refine=refine).system.GetSubsystemByName("link_position_estimator")
    ctx = lpe.CreateDefaultContext()
    S = dof_selection(c)
    rng = np.random.default_rng(11)
    h0 = c.h(np.zeros(c.num_joints))
    for _ in range(5):
        q = S @ rng.uniform(-0.6, 0.6, S.shape[1])
        q_prev = q + rng.normal(scale=0.05, size=q.size)
        theta = rng.uniform(-0.5, 0.5, rig.num_tendons)
        dh = c.h(q) - h0 + rng.normal(scale=1e-5, size=rig.num_tendons)   # a non-zero residual
        ctx.SetDiscreteState(q_prev)
        lpe.GetInputPort("motor_angle").FixValue(ctx, theta)
        lpe.GetInputPort("elongation").FixValue(ctx, rig.params.motor.pulley_radius * theta + dh + rig.offsets)
        lpe.GetInputPort("wrist_offset").FixValue(ctx, np.zeros(rig.num_tendons))
        got = lpe.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector().CopyToVector()
        want = np.zeros(c.num_joints)
        for name, part in c.parts.items():
            j, t = c.joint_slices[name], c.tendon_slices[name]
            if part.is_constant:
                want[j] = estimate_linear(part, dh[t])
            else:
                want[j] = estimate_thumb(part, dh[t], q_prev[j][:2], iterations=15)
                if refine:
                    r = dh[t] - (part.h(want[j]) - part.h(np.zeros(4)))
                    Sp = part.dof_selection
                    want[j] = want[j] + Sp @ (np.linalg.pinv(part.P(want[j]) @ Sp) @ r)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
        assert np.abs(got - q).max() < 1e-2


@pytest.mark.parametrize("finger", ["index", "thumb"])
def test_estimate_is_of_the_current_sample(finger):
    """The estimator's joint angles come from the sensor sample at hand (the same sample the forces a sampled
    controller reads with them come from), not from its stored state, which is only the next warm start: with
    the state at q0 and the measurements of a pose q1, the output is q1 ((5.15) exact for the index; the thumb
    base by Algorithm 1 warm-started at q0, within its 1e-4 rad convergence), the velocity the backward
    difference (q1 - q0) / T of the filter, and one periodic update stores q1."""
    from awiwi_drake.hand import finger_diagram
    rig = finger_diagram(finger=finger)
    est = rig.link_estimator()
    sys_ = est.system
    ctx = sys_.CreateDefaultContext()
    q0 = rig.operating_point().joint_angle
    q1 = q0 + np.array([0.05, 0.1, -0.08, 0.06])
    est.initialize(ctx, q0)
    c, r_m = rig.coupling, rig.params.motor.pulley_radius
    theta = np.linspace(-0.2, 0.3, c.num_tendons)
    x = r_m * theta + rig.offsets + np.asarray(c.h(q1)) - np.asarray(c.h(np.zeros(4)))
    sys_.GetInputPort("motor_angle").FixValue(ctx, theta)
    sys_.GetInputPort("elongation").FixValue(ctx, x)
    tol = 1e-12 if finger == "index" else 1e-4
    q = sys_.GetOutputPort("joint_angle").Eval(ctx)
    np.testing.assert_allclose(q, q1, atol=tol)
    T = max(LinkEstimatorParams().velocity_time_constant, est.period)
    np.testing.assert_allclose(sys_.GetOutputPort("joint_velocity").Eval(ctx), (q - q0) / T, rtol=1e-9, atol=1e-9)
    state = sys_.EvalUniquePeriodicDiscreteUpdate(ctx)
    np.testing.assert_allclose(state.get_vector(0).CopyToVector(), q, atol=1e-15)
