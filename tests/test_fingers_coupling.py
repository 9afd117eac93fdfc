"""Finger tendon routing: h(q), P(q) = dh/dq, stiffness map (5.12), kinematics (Table 5.1)."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, InitializeAutoDiff
from pydrake.symbolic import Evaluate, Expression, Jacobian, Variable

from _fd import fd_jacobian
from awiwi_drake.hand.coupling import (FingerCoupling, finger_coupling, hand_coupling, index_coupling_matrix,
                                       joint_stiffness, reduced_coupling_matrix)
from awiwi_drake.hand.kinematics import finger_frames, thumb_base_transform, thumb_frames
from awiwi_drake.parameters.hand import (FINGERS, TENDON_SLICES, RingFingerParams, ThumbParams,
                                         finger_params)

RNG = np.random.default_rng(1)


def _random_q(c, scale=0.8):
    return RNG.uniform(-scale, scale, c.num_joints)


@pytest.mark.parametrize("finger", FINGERS)
def test_P_matches_autodiff_and_finite_differences(finger):
    c = finger_coupling(finger)
    for _ in range(3):
        q = _random_q(c, 1.2)
        P = c.P(q)
        assert P.shape == (c.num_tendons, c.num_joints)
        np.testing.assert_allclose(P, fd_jacobian(c.h, q, h=1e-6), atol=1e-9)
        h_ad = c.h(InitializeAutoDiff(q).ravel())
        np.testing.assert_allclose(ExtractGradient(h_ad), P, atol=1e-14)
        # AutoDiff P (values) equals float P
        P_ad = c.P(InitializeAutoDiff(q).ravel())
        np.testing.assert_allclose(np.vectorize(lambda x: x.value() if isinstance(x, AutoDiffXd) else x)(P_ad),
                                   P, atol=1e-15)


def test_thumb_symbolic_h_differentiates_to_P():
    c = finger_coupling("thumb")
    qs = np.array([Variable(n) for n in c.joint_names])
    J = Jacobian(c.h(np.array([Expression(v) for v in qs])), qs)
    q = np.array([0.4, -0.7, 0.3, -0.2])
    env = dict(zip(qs, q))
    np.testing.assert_allclose(Evaluate(J, env), c.P(q), atol=1e-12)


def test_index_matrix_is_the_derivative_of_5_5():
    p = finger_params("index")
    P = finger_coupling("index").P()
    r0, r1, r2, r3 = p.abduction_radius, p.mcp_radius, p.pip_radius, p.dip_radius
    np.testing.assert_array_equal(P, index_coupling_matrix(r0, r1, r2, r3))
    assert P[0].tolist() == [r0, r1, 0, 0] and P[6].tolist() == [0, 0, r2, -r3]
    # antagonism: the tendons positively span the joint torques (tau = -P^T f, f >= 0):
    # for every joint direction there is a tendon that pulls each way.
    for j in range(4):
        assert (P[:, j] > 0).any() and (P[:, j] < 0).any()


def test_printed_5_9_differs_from_d_dq_of_5_5_in_rows_1_to_6():
    """(5.9) as printed beside d/dq of (5.5): rows 1-4 and 5-6 differ (rows 5 and 6 are swapped),
    rows 7-8 agree; the printed rows are a permutation of ours (the same spanned torques)."""
    r0, r1, r2, r3 = 0.006, 0.008, 0.007, 0.005
    printed = np.array([[r0, -r1, 0, 0], [-r0, -r1, 0, 0], [r0, r1, 0, 0], [-r0, r1, 0, 0],
                        [0, 0, -r2, 0], [0, 0, r2, 0], [0, 0, r2, -r3], [0, 0, -r2, r3]])
    ours = index_coupling_matrix(r0, r1, r2, r3)
    differs = [i + 1 for i in range(8) if not np.array_equal(printed[i], ours[i])]
    assert differs == [1, 2, 3, 4, 5, 6]
    np.testing.assert_array_equal(printed[[4, 5]], ours[[5, 4]])
    assert sorted(map(tuple, printed)) == sorted(map(tuple, ours))


def test_ring_coupling_reduces_to_5_18_for_equal_radii():
    p = RingFingerParams(pip_radius=0.006, dip_radius=0.006)
    c = finger_coupling("ring", p)
    R = reduced_coupling_matrix(c)
    assert R.shape == (6, 3)
    np.testing.assert_allclose(R[4:, 2], [0.012, -0.012])          # +-(r42 + r43) of (5.18)
    p2 = RingFingerParams()
    R2 = reduced_coupling_matrix(finger_coupling("ring", p2))
    ratio = p2.dip_radius / p2.pip_radius                            # (5.16)
    np.testing.assert_allclose(R2[4, 2], p2.pip_radius + p2.dip_radius * ratio)


def test_fifth_has_four_dof_and_eight_tendons():
    c = finger_coupling("fifth")
    assert (c.num_tendons, c.num_joints) == (8, 5)
    assert np.linalg.matrix_rank(reduced_coupling_matrix(c)) == 4


@pytest.mark.parametrize("finger", FINGERS)
def test_stiffness_map_is_symmetric_pd_and_equals_minus_dtau_dq(finger):
    c = finger_coupling(finger)
    k_t = RNG.uniform(5e3, 2e4, c.num_tendons)
    for _ in range(3):
        q0 = _random_q(c, 1.0)
        f0 = RNG.uniform(10, 40, c.num_tendons)    # feasible pretension: all tendons taut

        def tau(q):   # motors fixed: f = f0 + k_t (h(q) - h(q0))
            return -c.P(q).T @ (f0 + k_t * (c.h(q) - c.h(q0)))     # (ARCHITECTURE sign convention)

        K = joint_stiffness(c, q0, f0, k_t)
        np.testing.assert_allclose(K, K.T, atol=1e-12)
        np.testing.assert_allclose(K, -fd_jacobian(tau, q0, h=1e-6), rtol=1e-6, atol=1e-8)
        # positive definite on the independent DoF (ring/fifth: the DIP is held by the
        # coupling element, not by tendons, so K itself is singular along q_DIP - c q_PIP).
        # Constant P: K = S^T P^T K_t P S is PD for any k_t > 0 since P S has full column rank.
        # Thumb: only under a condition on the forces (here 10-40 N, ratio <= 4), see
        # test_thumb_stiffness_is_pd_over_the_workspace_for_balanced_forces_with_the_real_spring
        S = c.dof_selection
        assert np.linalg.eigvalsh(S.T @ K @ S).min() > 0
        if c.is_constant:
            P = c.P(q0)
            np.testing.assert_allclose(K, P.T @ np.diag(k_t) @ P, atol=1e-14)


def test_thumb_geometric_stiffness_term_is_the_tension_hessian():
    c = finger_coupling("thumb")
    q = np.array([0.5, 0.3, 0.0, 0.0])
    f = np.array([30.0, 10, 20, 25, 0, 0, 0, 0])
    H = c.tension_hessian(q, f)
    np.testing.assert_allclose(H, fd_jacobian(lambda qq: c.P(qq).T @ f, q, h=1e-6), atol=1e-8)
    assert np.abs(H[:2, :2]).max() > 0.1   # not negligible: ~f * L


def test_hand_coupling_is_block_diagonal_in_the_chosen_global_order():
    hc = hand_coupling(wrist_offsets=True)
    assert (hc.num_tendons, hc.num_finger_joints, hc.num_joints) == (38, 21, 59)
    q = RNG.uniform(-0.5, 0.5, hc.num_joints)
    P = hc.P(q)
    for f in FINGERS:
        c = finger_coupling(f)
        ts, js = TENDON_SLICES[f], hc.joint_slices[f]
        np.testing.assert_allclose(P[ts, js], c.P(q[js]))
        np.testing.assert_allclose(hc.h(q)[ts], c.h(q[js]) + q[21:][ts])
        off = np.ones(21, bool)
        off[js] = False
        assert not P[ts, :21][:, off].any()
    np.testing.assert_array_equal(P[:, 21:], np.eye(38))
    np.testing.assert_allclose(P, fd_jacobian(hc.h, q, h=1e-6), atol=1e-9)


def test_table_5_1_fingertip_closed_form():
    p = finger_params("index")
    tip0 = finger_frames(p, np.zeros(4))[-1][:3, 3]
    # M21 maps z to -y: lateral offsets of M76/M98 appear on +y
    np.testing.assert_allclose(tip0, [p.base_offset + p.proximal_length + p.middle_length + p.distal_length,
                                      -(p.middle_lateral + p.distal_lateral), 0.0], atol=1e-15)
    # flexing the MCP by 90 deg: the finger points along the MCP rotation (+y-> ... ) and
    # the distance MCP->tip is preserved (rigid chain).
    Ts = finger_frames(p, np.array([0.0, np.pi / 2, 0.0, 0.0]))
    assert np.linalg.norm(Ts[-1][:3, 3] - Ts[1][:3, 3]) == pytest.approx(
        np.linalg.norm(tip0 - finger_frames(p, np.zeros(4))[1][:3, 3]), abs=1e-12)
    # abduction rotates about the base z axis: the tip's z stays 0 and its distance to the axis is kept
    Ta = finger_frames(p, np.array([0.3, 0.0, 0.0, 0.0]))[-1][:3, 3]
    assert Ta[2] == pytest.approx(0.0, abs=1e-15)
    assert np.hypot(*Ta[:2]) == pytest.approx(np.hypot(*tip0[:2]), abs=1e-15)


def test_thumb_table_5_2_points_are_in_different_frames():
    p = ThumbParams()
    T = thumb_base_transform(p, 0.0, 0.0)
    c = finger_coupling("thumb", p)
    # at q = 0 every base tendon is parallel to the metacarpal and as long as it
    np.testing.assert_allclose(c.h(np.zeros(4))[:4], p.metacarpal_length)
    np.testing.assert_allclose(T[:3, 3], [p.metacarpal_length, 0, 0])
    np.testing.assert_allclose(thumb_frames(p, np.zeros(4))[1], T)


def test_bad_inputs_name_the_quantity():
    c = finger_coupling("index")
    with pytest.raises(ValueError, match="q20"):
        c.h(np.zeros(3))
    with pytest.raises(ValueError, match="finger"):
        finger_coupling("pinky")
    with pytest.raises(ValueError, match="k_t"):
        joint_stiffness(c, np.zeros(4), np.ones(8), np.ones(7))
    with pytest.raises(ValueError, match="ThumbParams.palm_points"):
        ThumbParams(palm_points=(0.0,) * 9)
    with pytest.raises(ValueError, match="pip_radius"):
        RingFingerParams(pip_radius=-1.0)


def test_finger_structure_flags_are_fixed_by_the_thesis():
    """pip_dip_coupled / has_hmc are not free: a ring with 8 tendons or a coupled index would
    silently change the hand's tendon count (38, Table 6.2) and the global tendon order."""
    from awiwi_drake.parameters.hand import (FifthFingerParams, FingerParams, HandParams,
                                             IndexFingerParams)
    for make, field in ((lambda: RingFingerParams(pip_dip_coupled=False), "RingFingerParams.pip_dip_coupled"),
                        (lambda: IndexFingerParams(pip_dip_coupled=True), "IndexFingerParams.pip_dip_coupled"),
                        (lambda: IndexFingerParams(has_hmc=True), "IndexFingerParams.has_hmc"),
                        (lambda: FifthFingerParams(has_hmc=False), "FifthFingerParams.has_hmc"),
                        (lambda: HandParams(ring=IndexFingerParams()), "HandParams.ring"),
                        (lambda: finger_coupling("ring", FingerParams()), "ring finger: FingerParams.pip_dip_coupled"),
                        (lambda: finger_coupling("ring", IndexFingerParams()), "index finger")):
        with pytest.raises(ValueError, match=field):
            make()
    # a generic FingerParams with the ring's structure is accepted and gives the ring's 6 tendons
    assert finger_coupling("ring", FingerParams(pip_dip_coupled=True)).num_tendons == 6


def test_global_tendon_order_mismatch_is_a_value_error(monkeypatch):
    import awiwi_drake.hand.coupling as hc
    swapped = dict(TENDON_SLICES, ring=slice(30, 36), fifth=slice(24, 32))
    monkeypatch.setattr(hc, "TENDON_SLICES", swapped)
    with pytest.raises(ValueError, match="ring finger's tendons occupy 25-30 of 38"):
        hc.hand_coupling()


def test_thumb_stiffness_is_pd_over_the_workspace_for_balanced_forces_with_the_real_spring():
    """Condition for K_q > 0 at the thumb base (the only place where the tension Hessian enters):
    the calibrated spring law (k_t(f) of the lever mechanism + Dyneema, FingerRigParams defaults),
    all four base tendons taut with forces in [f_min, 170 N] (the spring's range) and
    f_max / f_min <= 20.  Then on the base workspace [-1.5, 1.5]^2 every combination of forces at
    the extremes of that band gives lambda_min(K_base) >= 1.09 N m/rad.  The condition is real:
    a 2 N / 170 N imbalance (ratio 85) makes K indefinite at (0.5, -1.5) (lambda_min = -0.51)."""
    import itertools

    from awiwi_drake.components.spring import tendon_spring
    from awiwi_drake.parameters.hand import FingerRigParams
    c = finger_coupling("thumb")
    spring = tendon_spring(FingerRigParams.for_finger("thumb").spring)

    def k_of(f):
        f = np.asarray(f, dtype=float)
        return np.asarray(spring.stiffness(np.asarray(spring.inverse_force(f), dtype=float)), dtype=float)

    def lam_min(q_base, f_base):
        f = np.r_[f_base, np.full(4, 20.0)]
        return np.linalg.eigvalsh(joint_stiffness(c, np.r_[q_base, 0.0, 0.0], f, k_of(f))[:2, :2]).min()

    ax = np.linspace(-1.5, 1.5, 7)
    worst = np.inf
    for f_lo in (1.0, 8.5):                           # ratio 20: bands 1-20 N and 8.5-170 N
        for a, b in itertools.product(ax, ax):
            for combo in itertools.product((f_lo, 20.0 * f_lo), repeat=4):
                worst = min(worst, lam_min((a, b), combo))
    assert worst >= 1.0, worst
    # equal pretension over the whole spring range: PD, and stiffer with force (lever spring)
    lam_eq = [min(lam_min((a, b), np.full(4, f0)) for a, b in itertools.product(ax, ax)) for f0 in (1, 20, 170)]
    assert 0 < lam_eq[0] < lam_eq[1] < lam_eq[2]
    assert lam_min((0.5, -1.5), (2.0, 170.0, 2.0, 2.0)) < 0.0


def test_thumb_base_lengths_and_jacobian_from_one_kinematics_evaluation():
    """Algorithm 1's fast path (lengths and dh/dq of the base tendons together, a kernel compiled from the
    laws h and P) against h(q) and P(q) to 1e-12 and against finite differences of h."""
    c = finger_coupling("thumb")
    for q in RNG.uniform(-1.2, 1.2, size=(5, 2)):
        out = c._base_kernel()(np.asarray(q, dtype=float), np.empty(28))
        h, J = out[:4], out[4:12].reshape(4, 2)
        full = np.concatenate([q, [0.0, 0.0]])
        np.testing.assert_allclose(h, c.h(full)[:4], rtol=1e-12, atol=0)
        np.testing.assert_allclose(J, c.P(full)[:4, :2], rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(J, fd_jacobian(lambda qq: c.h(np.concatenate([qq, [0.0, 0.0]]))[:4], q, h=1e-6),
                                   atol=1e-9)
    np.testing.assert_allclose(c.distal_pseudo_inverse() @ c.P(np.zeros(4))[4:, 2:], np.eye(2), atol=1e-12)
    # the float h(q), P(q) and tension Hessians come from the same kernel: equal to the laws' generic path
    for q in RNG.uniform(-1.2, 1.2, size=(3, 4)):
        generic = np.array(q, dtype=object)
        np.testing.assert_allclose(c.h(q), np.asarray(c.h(generic), dtype=float), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(c.P(q), np.asarray(c.P(generic), dtype=float), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(c.tension_hessians(q), np.asarray(FingerCoupling.tension_hessians(c, generic),
                                                                     dtype=float), rtol=1e-12, atol=1e-15)
