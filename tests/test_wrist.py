"""Wrist kinematics and tendon lengths (thesis ch. 6): physics checks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydrake.autodiffutils import AutoDiffXd
from pydrake.symbolic import Expression, Variable

from _fd import fd_jacobian
from awiwi_drake.hand.wrist import (
    TENDON_FINGERS,
    wrist_compensation,
    wrist_constraint_errors,
    wrist_jacobian,
    wrist_kinematics,
    wrist_tendon_lengths,
    wrist_tendon_offsets,
)
from awiwi_drake.reproductions.ch06_wrist import wrist_motion_study
from awiwi_drake.parameters.wrist import TABLE_6_2_FOREARM, TABLE_6_2_PALM, WristParams

P = WristParams()
DEG = math.pi / 180.0
# Configurations inside the thesis's motion (30 deg flexion, 20 deg abduction) and beyond.
CONFIGS = [(0.0, 0.0), (0.0, 30 * DEG), (20 * DEG, 0.0), (20 * DEG, 30 * DEG),
           (-15 * DEG, -25 * DEG), (0.3, -0.4)]


@pytest.fixture(scope="module")
def study():
    return wrist_motion_study()


# --- Table 6.1 / 6.2 -------------------------------------------------------
def test_table_6_1_and_derived_radii():
    a, b, c = 0.050, 0.042, 0.036
    assert (P.length, P.width, P.thickness) == (a, b, c)
    assert P.crank_length == pytest.approx(math.sqrt(a * a + b * b + c * c), rel=1e-15)
    assert P.coupler_length == c and P.palm_radius == b
    assert P.link_length == pytest.approx(math.hypot(a, b), rel=1e-15)


def test_table_6_2_transcription():
    F, Pm = P.forearm_offset_array, P.palm_offset_array
    assert F.shape == Pm.shape == (38, 3)
    assert len(TABLE_6_2_FOREARM) == len(TABLE_6_2_PALM) == 114
    # spot rows as printed (1-based tendon numbers)
    assert F[0].tolist() == [0.004, 0.007, 0.008] and Pm[0].tolist() == [-0.004, -0.011, 0.010]
    assert F[18].tolist() == [0.004, 0.035, 0.008] and Pm[18].tolist() == [-0.004, 0.018, 0.010]
    assert F[19].tolist() == [0.004, 0.006, 0.028] and Pm[19].tolist() == [-0.004, -0.013, -0.010]
    assert F[37].tolist() == [0.004, 0.035, 0.028] and Pm[37].tolist() == [-0.004, 0.016, -0.010]
    # structure: x constant, two layers of 19, y strictly increasing within a layer
    assert np.all(F[:, 0] == 0.004) and np.all(Pm[:, 0] == -0.004)
    assert np.all(F[:19, 2] == 0.008) and np.all(F[19:, 2] == 0.028)
    assert np.all(Pm[:19, 2] == 0.010) and np.all(Pm[19:, 2] == -0.010)
    for layer in (slice(0, 19), slice(19, 38)):
        assert np.all(np.diff(F[layer, 1]) > 0) and np.all(np.diff(Pm[layer, 1]) > 0)
    # forearm layer 1: 0.007 + 0.0016 k truncated to mm (pattern of the printed values)
    k = np.arange(19)
    np.testing.assert_allclose(F[:19, 1], np.floor(7 + 1.6 * k + 1e-9) / 1000, atol=1e-15)
    assert len(TENDON_FINGERS) == 38 and TENDON_FINGERS.count("ring") == 6


def test_params_validation():
    with pytest.raises(ValueError, match="WristParams.width"):
        WristParams(width=-0.01)
    with pytest.raises(ValueError, match="palm_offsets"):
        WristParams(palm_offsets=(0.0,) * 6)
    with pytest.raises(ValueError, match="palm_offsets"):
        WristParams(palm_offsets=(0.0,) * 7)


# --- kinematics ------------------------------------------------------------
def test_neutral_wrist_is_the_box():
    a, b, c = P.length, P.width, P.thickness
    pose = wrist_kinematics(0.0, 0.0)
    np.testing.assert_allclose(pose.B, [a, b, c], atol=1e-15)
    np.testing.assert_allclose(pose.C, [a, b, 0.0], atol=1e-15)
    np.testing.assert_allclose(pose.A, [a, 0.0, c / 2], atol=1e-15)
    np.testing.assert_allclose(pose.rotation, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(pose.origin, [a, b / 2, c / 2], atol=1e-15)
    np.testing.assert_allclose(wrist_tendon_offsets(0.0, 0.0), 0.0, atol=0.0)
    # neutral tendon lengths: straight segments between the Table 6.2 points
    palm = P.palm_offset_array + [a, b / 2, c / 2]
    np.testing.assert_allclose(wrist_tendon_lengths(0.0, 0.0),
                               np.linalg.norm(palm - P.forearm_offset_array, axis=1), atol=1e-15)


def test_table_6_2_is_consistent_with_the_reconstruction():
    """Evidence for the box construction from Table 6.2 alone (see hand/wrist.py)."""
    a, c = P.length, P.thickness
    h0 = wrist_tendon_lengths(0.0, 0.0)
    assert np.ptp(h0) < 0.5e-3                    # all 38 neutral paths nearly equal (46.6 mm)
    # side view: every tendon passes through the flexion crossing point (a/2, c/2)
    F, W = P.forearm_offset_array, P.palm_offset_array + [a, 0.0, c / 2]
    np.testing.assert_allclose(0.5 * (F[:, [0, 2]] + W[:, [0, 2]]), np.tile([a / 2, c / 2], (38, 1)),
                               atol=1e-15)


@pytest.mark.parametrize("q", CONFIGS)
def test_constraints_and_frame(q):
    pose = wrist_kinematics(*q)
    assert np.max(np.abs(wrist_constraint_errors(pose))) < 1e-15
    R = pose.rotation
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-15)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-14)
    # B, C, B0, C0 coplanar with the axis B0C0 (z) rotated by q71 (Fig 6.4)
    g = math.atan2(P.width, P.length) + q[0]
    n = np.array([-math.sin(g), math.cos(g), 0.0])
    assert abs(pose.B @ n) < 1e-15 and abs(pose.C @ n) < 1e-15
    # the homogeneous transform maps palm origin/axes
    T = pose.transform()
    np.testing.assert_allclose(T[:3, 3], pose.origin)


@pytest.mark.parametrize("q73", [-40 * DEG, 0.0, 10 * DEG, 30 * DEG, 60 * DEG])
def test_t_C_matches_6_3_and_discards_parallelogram(q73):
    pose = wrist_kinematics(0.0, q73)
    L, d = P.crank_length, P.coupler_length
    tB = pose.t_B
    num = (d * d + L * L) * math.sin(tB) - 2 * L * d
    den = (L * L - d * d) * math.cos(tB)
    assert math.tan(pose.t_C) == pytest.approx(num / den, rel=1e-12)      # (6.3), second solution
    # (6.2) in the plane, with C0 = (0, D_BC): both branches satisfy |BC| = D_BC ...
    B = L * np.array([math.cos(tB), math.sin(tB)])
    for tC in (pose.t_C, tB):
        C = np.array([0.0, d]) + L * np.array([math.cos(tC), math.sin(tC)])
        assert np.linalg.norm(B - C) == pytest.approx(d, rel=1e-12)
    # ... but t_C = t_B is the (discarded) parallelogram: ours crosses
    assert abs(math.remainder(pose.t_C - tB, 2 * math.pi)) > 0.1


def test_jacobian_at_neutral_is_twice_rotation_about_centre():
    """Crossed four-bars: the palm turns at twice the crank rate about the wrist centre.

    At q = 0 the instantaneous screw of the palm is 2 z (abduction) and 2 n
    (flexion, n the normal of the BC plane), both through (a/2, b/2, c/2);
    dh_i/dq = u_i . (omega x (W_i - centre)), u_i the unit tendon direction.
    """
    a, b, c = P.length, P.width, P.thickness
    centre = np.array([a / 2, b / 2, c / 2])
    W = P.palm_offset_array + [a, b / 2, c / 2]
    u = W - P.forearm_offset_array
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    n = np.array([-b, a, 0.0]) / math.hypot(a, b)
    expected = np.column_stack([np.sum(u * np.cross(2 * w, W - centre), axis=1)
                                for w in (np.array([0.0, 0.0, 1.0]), n)])
    np.testing.assert_allclose(wrist_jacobian(0.0, 0.0), expected, atol=1e-13)


@pytest.mark.parametrize("q", CONFIGS[1:])
def test_jacobian_matches_finite_differences(q):
    J = wrist_jacobian(*q)
    fd = fd_jacobian(lambda qq: wrist_tendon_offsets(*qq), q, h=1e-6)
    assert J.shape == (38, 2)
    np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-9)


def test_jacobian_is_generic_and_exact():
    """P(q) = dh/dq is exact for every scalar type: it equals AutoDiffXd of the lengths h, its own AutoDiffXd
    (the Hessian of h) is symmetric and equals finite differences of P, and the symbolic P evaluates to it."""
    q = np.array([0.12, -0.3])
    P = wrist_jacobian(*q)
    h_ad = wrist_tendon_lengths(AutoDiffXd(q[0], [1.0, 0.0]), AutoDiffXd(q[1], [0.0, 1.0]))
    np.testing.assert_allclose(P, np.array([e.derivatives() for e in h_ad]), atol=1e-15)
    P_ad = wrist_jacobian(AutoDiffXd(q[0], [1.0, 0.0]), AutoDiffXd(q[1], [0.0, 1.0]))
    H = np.array([[e.derivatives() for e in row] for row in P_ad])           # (38, 2, 2)
    np.testing.assert_allclose(H[:, 0, 1], H[:, 1, 0], atol=1e-14)
    H_fd = fd_jacobian(lambda qq: wrist_jacobian(*qq), q, h=1e-6).reshape(38, 2, 2)
    np.testing.assert_allclose(H, H_fd, rtol=1e-5, atol=1e-8)
    x = [Variable("a"), Variable("b")]
    P_sym = wrist_jacobian(Expression(x[0]), Expression(x[1]))
    env = {x[0]: q[0], x[1]: q[1]}
    np.testing.assert_allclose([P_sym[i, j].Evaluate(env) for i, j in ((0, 0), (37, 1))], P[[0, 37], [0, 1]],
                               atol=1e-15)


def test_scalar_types_agree():
    q = (0.2, 0.35)
    ref = wrist_tendon_offsets(*q)
    ad = wrist_tendon_offsets(AutoDiffXd(q[0], [1.0, 0.0]), AutoDiffXd(q[1], [0.0, 1.0]))
    np.testing.assert_allclose([e.value() for e in ad], ref, atol=1e-16)
    x, y = Variable("q71"), Variable("q73")
    sym = wrist_tendon_offsets(x, y)
    env = {x: q[0], y: q[1]}
    np.testing.assert_allclose([e.Evaluate(env) for e in sym[[0, 18, 37]]], ref[[0, 18, 37]], atol=1e-15)


def test_pure_abduction_is_planar_and_flexion_symmetric_in_the_box():
    # q73 = 0: the motion is mirror-symmetric about z = c/2: palm turns about z only
    R = wrist_kinematics(25 * DEG, 0.0).rotation
    np.testing.assert_allclose(R[2], [0.0, 0.0, 1.0], atol=1e-15)
    assert math.atan2(R[1, 0], R[0, 0]) > 25 * DEG  # crossed linkage amplifies the crank angle


def test_out_of_range_raises():
    with pytest.raises(ValueError, match=r"wrist_angle \[q71, q73\]"):
        wrist_tendon_offsets(0.0, -1.2)
    with pytest.raises(ValueError, match="q71 = nan rad is not finite"):
        wrist_tendon_offsets(float("nan"), 0.0)
    with pytest.raises(ValueError, match="params"):
        wrist_tendon_offsets(0.0, 0.0, params={"length": 0.05})
    with pytest.raises(ValueError, match="motor_pulley_radius"):
        wrist_compensation(0.1, 0.1, -0.005)
    with pytest.raises(ValueError, match="motor_pulley_radius"):
        wrist_compensation(0.1, 0.1, np.full(5, 0.005))


def test_compensation_cancels_elongation():
    r = np.linspace(0.004, 0.006, 38)
    dtheta = wrist_compensation(0.2, -0.3, r)
    np.testing.assert_allclose(r * dtheta + wrist_tendon_offsets(0.2, -0.3), 0.0, atol=1e-17)


# --- thesis figures --------------------------------------------------------
def test_fig_6_9_constraint_errors(study):
    """Fig 6.9: constraint errors at numerical precision (thesis < 6e-14 m)."""
    assert study.constraint_errors.shape == (study.t.size, 6)
    assert study.max_constraint_error < 1e-12
    # the closed-form branch is followed continuously (no jump to the mirror solution)
    assert np.max(np.abs(np.diff(study.offsets, axis=0))) < 1e-3
    assert np.max(np.abs(np.degrees(study.wrist_angle)), axis=0) == pytest.approx([20.0, 30.0])


def test_fig_6_10_tendon_displacements(study):
    """Fig 6.10: abduction moves tendons in proportion to their distance from the median axis.

    Flexion moves them less.  Magnitude: NOT reproduced (docs/REPRODUCTIONS.md: the thesis's
    axis spans -0.015..0.03 m, ours about half, set by the reconstructed linkage whose lengths
    are not printed).  Checked here: the displacements are the path integral of the tendon
    Jacobian along the recorded wrist motion (the Jacobian itself is checked against the
    closed-form screw at neutral above), and their shape.
    """
    hi = float(np.max(study.offsets))
    assert study.abduction_peak == pytest.approx(hi, abs=1e-9)          # the peak is the abduction's
    q = np.asarray(study.wrist_angle)
    J = np.array([wrist_jacobian(*qk) for qk in q])                       # (N, 38, 2)
    rate = np.einsum("kij,kj->ki", 0.5 * (J[1:] + J[:-1]), np.diff(q, axis=0))
    integral = study.offsets[0] + np.concatenate([np.zeros((1, 38)), np.cumsum(rate, axis=0)])
    # trapezoid rule: error of order (third derivative of h) |dq|^2 per unit path, below 1e-3 of the peak at this sampling
    np.testing.assert_allclose(integral, study.offsets, atol=1e-3 * hi)
    assert study.abduction_r2 > 0.99
    # tendons on the y > b/2 side shorten, slope about 2 x 20 deg (crossed linkage)
    assert -2.5 * 20 * DEG < study.abduction_slope < -1.5 * 20 * DEG
    # the zero-displacement line lies within 5 mm of the median axis y = b/2 (the
    # Table 6.2 palm points sit 2.5 mm off it) and the fit leaves < 5 % of the peak
    assert abs(study.abduction_intercept / study.abduction_slope) < 0.005
    peak = study.offsets[np.argmax(np.abs(study.wrist_angle[:, 0]))]
    fit = study.abduction_slope * study.median_distance + study.abduction_intercept
    assert np.max(np.abs(peak - fit)) < 0.05 * study.abduction_peak
    # the peak is the slope times the largest lateral distance from the zero line (within the fit error)
    zero_line = -study.abduction_intercept / study.abduction_slope
    lever = np.max(np.abs(study.median_distance - zero_line))
    assert study.abduction_peak == pytest.approx(abs(study.abduction_slope) * lever, rel=0.05)
    assert study.flexion_to_abduction_ratio < 0.6
    # tendons near the zero-displacement line barely move, side ones most
    offset_line = -study.abduction_intercept / study.abduction_slope
    centre = np.abs(study.median_distance - offset_line) < 0.002
    side = np.abs(study.median_distance - offset_line) > 0.012
    assert np.max(np.abs(peak[centre])) < 0.2 * np.min(np.abs(peak[side]))
    # nonlinear in the angle (thesis: "the relationship ... is nonlinear")
    half = wrist_tendon_offsets(10 * DEG, 0.0)
    assert np.max(np.abs(peak - 2 * half)) > 1e-3


def test_held_flexion_variant_keeps_constraints():
    res = wrist_motion_study(hold_flexion=True, num_samples=41)
    assert res.max_constraint_error < 1e-12
    assert np.allclose(res.wrist_angle[res.phase == "abduction", 1], 30 * DEG)
    assert res.abduction_r2 > 0.85 and res.abduction_slope < 0


def test_motion_study_validation():
    with pytest.raises(ValueError, match="duration"):
        wrist_motion_study(duration=0.0)
    with pytest.raises(ValueError, match="num_samples"):
        wrist_motion_study(num_samples=2)


def test_plot_uses_the_study(study):
    import matplotlib

    matplotlib.use("Agg")
    fig, ax = study.plot(panel="displacements")
    lines = ax.get_lines()
    assert len(lines) == 38
    np.testing.assert_array_equal(lines[5].get_ydata(), study.offsets[:, 5])
    fig2, (ax2, ax3) = study.plot()
    assert np.max(ax2.get_lines()[0].get_ydata()) == pytest.approx(study.max_constraint_error)
    assert len(ax3.get_lines()) == 38
    with pytest.raises(ValueError, match="WristMotionResult.plot: panel 'offsets'"):
        study.plot(panel="offsets")
    import matplotlib.pyplot as plt

    plt.close(fig)
    plt.close(fig2)
