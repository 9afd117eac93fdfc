"""Finger MultibodyPlants: Table 5.1 kinematics, coupling element, Coriolis term system."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.autodiffutils import ExtractGradient, ExtractValue, InitializeAutoDiff

from _fd import fd_jacobian
from awiwi_drake.hand.kinematics import finger_frames, thumb_frames
from awiwi_drake.hand.plant import coupling_force_gain, make_finger_plant, make_hand_plant
from awiwi_drake.hand.systems import CoriolisCancellation
from awiwi_drake.parameters.hand import FINGERS, HandParams, finger_params


@pytest.mark.parametrize("finger", FINGERS)
def test_plant_forward_kinematics_equals_table_5_1(finger):
    plant, model = make_finger_plant(finger)
    ctx = plant.CreateDefaultContext()
    p = finger_params(finger)
    rng = np.random.default_rng(7)
    for _ in range(3):
        q = rng.uniform(-1.2, 1.2, plant.num_positions())
        plant.SetPositions(ctx, q)
        X = plant.CalcRelativeTransform(ctx, plant.world_frame(), model.tip_body.body_frame())
        ref = (thumb_frames(p, q) if finger == "thumb" else finger_frames(p, q))[-1]
        np.testing.assert_allclose(X.multiply(model.tip_offset), ref[:3, 3], atol=1e-15)


def test_link_masses_follow_the_finger_geometry():
    """Masses: 0.02 kg (section 5.2.2) less the abduction link, split by link length (Table 5.1); the
    distal inertia about the DIP is the cylinder's m (L^2/3 + R^2/4) (6.2e-7 kg m^2, not the test rig's
    7.2e-7 of Table 15.1, which belongs to the single-joint rig)."""
    plant, model = make_finger_plant("index")
    ctx = plant.CreateDefaultContext()
    M = plant.CalcMassMatrix(ctx)
    p = finger_params("index")
    masses = np.array([p.proximal_mass, p.middle_mass, p.distal_mass])
    lengths = np.array([p.proximal_length, p.middle_length, p.distal_length])
    assert masses.sum() + p.abduction_link_mass == pytest.approx(0.02, rel=1e-3)
    np.testing.assert_allclose(masses / masses.sum(), lengths / lengths.sum(), rtol=2e-3)
    assert M[3, 3] == pytest.approx(p.distal_mass * (p.distal_length ** 2 / 3 + p.link_radius ** 2 / 4), rel=1e-9)
    # about the MCP (q = 0, straight finger): closed form sum of cylinder inertias + parallel axis
    # (the lateral offsets of M76/M98 lie along the flexion axis and do not count)
    p = finger_params("index")
    R, start, expected = p.link_radius, 0.0, 0.0
    for m, L in ((p.proximal_mass, p.proximal_length), (p.middle_mass, p.middle_length),
                 (p.distal_mass, p.distal_length)):
        expected += m * (L ** 2 / 12 + R ** 2 / 4) + m * (start + L / 2) ** 2
        start += L
    assert M[1, 1] == pytest.approx(expected, rel=1e-12)


def test_coupling_element_is_a_spring_on_dip_minus_ratio_pip():
    hp = HandParams()
    plant, models = make_hand_plant(hp)
    G = coupling_force_gain(plant, models)
    n = plant.num_positions()
    K = G[:, :n]
    np.testing.assert_allclose(K, K.T)
    assert np.linalg.eigvalsh(K).min() > -1e-12
    q = np.zeros(n)
    ring = models["ring"]
    ip, idp = ring.joints[2].position_start(), ring.joints[3].position_start()
    q[ip] = 0.5
    q[idp] = 0.5 * hp.ring.dip_pip_ratio           # on the coupling manifold (5.16): no force
    np.testing.assert_allclose(K @ q, 0.0, atol=1e-15)
    q[idp] += 0.01                                 # off it: restoring torque k_c * 0.01 on the DIP
    assert (-(K @ q))[idp] == pytest.approx(-hp.ring.coupling_stiffness * 0.01)
    assert np.count_nonzero(np.abs(K).sum(axis=0)) == 4   # ring PIP/DIP and fifth PIP/DIP only


def test_coriolis_term_system_converts_and_satisfies_skew_symmetry():
    plant, _ = make_finger_plant("index")
    sys = CoriolisCancellation(plant)
    ad = sys.ToAutoDiffXd()
    rng = np.random.default_rng(2)
    x = np.r_[rng.uniform(-1, 1, 4), rng.uniform(-3, 3, 4)]
    ctx = ad.CreateDefaultContext()
    ad.get_input_port(0).FixValue(ctx, InitializeAutoDiff(x).ravel())
    y = ad.get_output_port(0).Eval(ctx)
    fctx = sys.CreateDefaultContext()

    def f(xx):
        sys.get_input_port(0).FixValue(fctx, xx)
        return sys.get_output_port(0).Eval(fctx).copy()

    eps = 1e-6
    J = fd_jacobian(f, x, h=eps)
    np.testing.assert_allclose(ExtractValue(y).ravel(), f(x), rtol=1e-12)
    np.testing.assert_allclose(ExtractGradient(y), J, atol=1e-9)
    # physics: v^T C(q,v) v = 1/2 v^T Mdot v, and C(q, a v) a v = a^2 C(q,v) v
    pc = plant.CreateDefaultContext()
    q, v = x[:4], x[4:]

    def M(qq):
        plant.SetPositions(pc, qq)
        return plant.CalcMassMatrix(pc)

    Mdot = (M(q + eps * v) - M(q - eps * v)) / (2 * eps)
    assert v @ f(x) == pytest.approx(0.5 * v @ Mdot @ v, rel=1e-6)
    np.testing.assert_allclose(f(np.r_[q, 2 * v]), 4 * f(x), rtol=1e-12)


def test_fig_5_7_coriolis_effect_vanishes_at_least_quadratically_with_the_deflection():
    """Fig 5.7: release an MCP flexion deflection (the thesis's "second joint", abduction
    at 0) with motors fixed, with and without C(q, v) v.

    v scales with the deflection d and the Coriolis/centrifugal torques with v^2,
    so the trajectory difference shrinks at least 4x when d halves.  Measured
    (0.05 -> 0.025 rad, 0.02 s): 4.0x on the abduction (the lateral offsets of
    M76/M98 make the finger non-planar: a v^2 torque already at q = 0) and 8.0x on
    MCP/PIP/DIP (in a planar chain the terms are ~ sin(q) v^2 ~ d^3).  We assert
    >= 3.9x and >= 7x.  The thesis's 1e-3 rad bound over 0.2 s holds at 0.025 rad.
    """
    from awiwi_drake.reproductions.ch05_fingers import coriolis_study
    big = coriolis_study("index", deflection=0.05, t_final=0.02)
    small = coriolis_study("index", deflection=0.025, t_final=0.02)
    ratio = big.max_abs_difference / small.max_abs_difference
    assert ratio[0] >= 3.9 and np.all(ratio[1:] >= 7.0), ratio
    np.testing.assert_allclose(big.q_full[0], [0.0, 0.05, 0.0, 0.0])           # the MCP is the deflected joint
    assert np.max(np.abs(big.q_full[:, 1])) == pytest.approx(0.05, rel=1e-6)   # released from rest
    # the abduction is "not influenced" (thesis): < 0.2 % of the MCP deflection
    assert np.max(np.abs(big.q_full[:, 0])) < 2e-3 * 0.05
    import matplotlib.pyplot as plt
    fig, ax = big.plot()                                    # Fig 5.7 draws the difference, one line per joint
    np.testing.assert_array_equal(np.array([ln.get_ydata() for ln in ax.get_lines()]), big.difference.T)
    plt.close(fig)
    full = coriolis_study("index", deflection=0.025, t_final=0.2, num_samples=201)
    assert np.all(full.max_abs_difference < 1e-3)      # the thesis's bound, its 0.2 s horizon


def test_motor_angle_reference_converts_and_keeps_the_springs_at_their_operating_elongation():
    from awiwi_drake.hand.coupling import finger_coupling
    from awiwi_drake.hand.systems import MotorAngleReference
    c = finger_coupling("thumb")
    theta_op, q_op, r_m = np.linspace(-0.2, 0.2, 8), np.zeros(4), 0.005
    sys = MotorAngleReference(c, r_m, theta_op, q_op)
    ctx = sys.CreateDefaultContext()
    q = np.array([0.5, 0.35, 0.3, -0.2])

    def out(qq):
        sys.get_input_port(0).FixValue(ctx, qq)
        return sys.get_output_port(0).Eval(ctx).copy()

    theta = out(q)
    # elongation r_m theta + h(q) - h(0) equals its operating value for every tendon
    np.testing.assert_allclose(r_m * theta + c.h(q), r_m * theta_op + c.h(q_op), atol=1e-15)
    # the float system keeps its last result for a repeated reference; any change recomputes
    for qq in (q, q + [0.0, 1e-9, 0.0, 0.0], q_op, q):
        np.testing.assert_allclose(r_m * out(qq) + c.h(qq), r_m * theta_op + c.h(q_op), atol=1e-15)
    assert not np.array_equal(out(q), out(q + [0.0, 1e-9, 0.0, 0.0]))
    ad = sys.ToAutoDiffXd()
    actx = ad.CreateDefaultContext()
    ad.get_input_port(0).FixValue(actx, InitializeAutoDiff(q).ravel())
    J = ExtractGradient(ad.get_output_port(0).Eval(actx))
    np.testing.assert_allclose(J, -c.P(q) / r_m, atol=1e-12)


@pytest.mark.parametrize("finger", ["ring", "fifth"])
def test_loaded_dip_coupling_error_matches_the_predicted_compliance(finger):
    """A static torque on the DIP, motors held: the coupling error q_DIP - c q_PIP equals
    c^T K_q^-1 e_DIP tau (K_q: the operating point's joint stiffness, tendons + coupling
    element) = tau / (k_c (1 + c^2)), since the PIP/DIP tendon pair acts along (r2, r3),
    orthogonal to the coupling direction.  Checked on the nonlinear diagram's equilibrium."""
    from scipy.optimize import fsolve

    from awiwi_drake.hand.diagrams import finger_diagram
    from awiwi_drake.hand.plant import coupling_compliance
    from awiwi_drake.reproductions.ch05_fingers import fixed_motor_diagram
    from awiwi_drake.parameters.hand import FingerRigParams
    p = FingerRigParams.for_finger(finger)
    fp = p.finger
    rig = finger_diagram(finger=finger, params=p)
    op = rig.operating_point(pretension=p.pretension)
    c = rig.models.coupling_vector
    comp = coupling_compliance(op.joint_stiffness, c)
    assert comp == pytest.approx(1.0 / (fp.coupling_stiffness * (1 + fp.dip_pip_ratio ** 2)), rel=1e-9)

    diagram, plant = fixed_motor_diagram(finger, p)
    n = plant.num_positions()
    ctx = diagram.CreateDefaultContext()
    tau = np.zeros(n)
    tau[-1] = 0.02                       # N m on the DIP (1 N at the 2 cm distal phalanx)
    diagram.GetInputPort("external_torque").FixValue(ctx, tau)

    def vdot(q):
        ctx.SetContinuousState(np.r_[q, np.zeros(n)])
        return diagram.EvalTimeDerivatives(ctx).CopyToVector()[n:]

    q_lin = np.linalg.solve(op.joint_stiffness, tau)   # linear prediction: start of the search
    q_eq, info, ok, msg = fsolve(vdot, q_lin, full_output=True, xtol=1e-13)
    assert ok == 1, msg
    err = c @ q_eq
    # exact up to the solver: the coupling element is linear and the tendon pair cannot see c
    assert err == pytest.approx(comp * tau[-1], rel=1e-4), (err, comp * tau[-1])
    assert err > 0.0                      # the DIP gives way in the direction it is pushed


def test_fifth_hmc_moves_the_finger_towards_the_palm_centre():
    """Section 5.5: the HMC gives 'a locking motion towards the palm center'.  The chosen axis is
    perpendicular to the metacarpal (a rotation about the bone's own axis would spin it in place,
    leaving the finger base where it is) and flexing it brings base and fingertip closer."""
    from awiwi_drake.hand.plant import palm_centre
    hp = HandParams()
    plant, models = make_hand_plant(hp)
    ctx = plant.CreateDefaultContext()
    m = models["fifth"]
    hmc, abd = m.joints[0], m.joints[1]
    X_WB = plant.CalcRelativeTransform(ctx, plant.world_frame(), hmc.frame_on_parent())
    axis_W = X_WB.rotation().multiply(hmc.revolute_axis())
    bone_W = X_WB.rotation().multiply([1.0, 0.0, 0.0])            # the metacarpal runs along base x
    assert abs(axis_W @ bone_W) < 1e-15

    def points(q5h):
        q = np.zeros(plant.num_positions())
        q[hmc.position_start()] = q5h
        plant.SetPositions(ctx, q)
        base = plant.CalcPointsPositions(ctx, abd.frame_on_child(), np.zeros((3, 1)), plant.world_frame())
        tip = plant.CalcPointsPositions(ctx, m.tip_body.body_frame(), m.tip_offset.reshape(3, 1),
                                        plant.world_frame())
        return base.ravel(), tip.ravel()

    c = palm_centre(hp)
    b0, t0 = points(0.0)
    for q5h in (0.1, 0.3):
        b, t = points(q5h)
        # the base moves on a circle of radius hmc_offset (not in place), towards the palm centre
        assert np.linalg.norm(b - b0) == pytest.approx(2 * hp.fifth.hmc_offset * np.sin(q5h / 2), rel=1e-12)
        assert np.linalg.norm(b - c) < np.linalg.norm(b0 - c)
        assert np.linalg.norm(t - c) < np.linalg.norm(t0 - c)
        assert t[2] > t0[2] and t[1] > t0[1]      # palmar (+z) and radially, towards the thumb side (+y)
    # first order: d|tip - c|/dq < 0 at the straight pose (a pure flexion axis would give 0 here)
    eps = 1e-6
    d = (np.linalg.norm(points(eps)[1] - c) - np.linalg.norm(points(-eps)[1] - c)) / (2 * eps)
    assert d < -0.1 * hp.fifth.hmc_offset
