"""Stiffness correction (ch. 8): (8.1) closed form, positive definiteness, online correction on the joint rig."""

import numpy as np
import pytest

from _fd import check_system_autodiff_matches_fd

from awiwi_drake.control.stiffness_correction import (
    StiffnessCorrectedImpedance, impedance_for_effective_stiffness, pretension_elongation)
from awiwi_drake.reproductions.ch08_stiffness_correction import stiffness_correction_run
from awiwi_drake.parameters.hand_control import StiffnessCorrectionParams
from awiwi_drake.rigs import joint_rig


def test_series_law_recovers_the_target_and_stays_positive_definite():
    rng = np.random.default_rng(2)
    A = rng.normal(size=(3, 3))
    K_eff = A @ A.T + 0.5 * np.eye(3)
    K_mech = 2.0 * K_eff                                 # (8.2) with eps = 2
    K_imp, limited = impedance_for_effective_stiffness(K_eff, K_mech)
    assert not limited
    np.testing.assert_allclose(K_imp, K_imp.T, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(K_imp) > 0)
    np.testing.assert_allclose(np.linalg.inv(np.linalg.inv(K_imp) + np.linalg.inv(K_mech)), K_eff, rtol=1e-10)  # (8.1)
    np.testing.assert_allclose(K_imp, 2.0 * K_eff, rtol=1e-10)      # eps/(eps-1) K_eff for eps = 2
    # K_mech below the target in one direction: K_imp stays positive definite, reported as limited
    K_imp2, limited2 = impedance_for_effective_stiffness(np.eye(2), np.diag([3.0, 0.5]))
    assert limited2 and np.all(np.linalg.eigvalsh(K_imp2) > 0)
    with pytest.raises(ValueError, match="K_mech"):
        impedance_for_effective_stiffness(np.eye(2), -np.eye(2))


def test_pretension_sets_the_mechanical_stiffness():
    rig = joint_rig()
    rq = rig.params.link_pulley_radius
    x = pretension_elongation(rig.spring, 1.5, rq)
    assert 2 * rq ** 2 * float(rig.spring.stiffness(np.array([x]))[0]) == pytest.approx(1.5, rel=1e-6)
    with pytest.raises(ValueError, match="outside the spring"):
        pretension_elongation(rig.spring, 1e6, rq)


def test_controller_autodiff_matches_finite_differences_and_closed_form_gains():
    """AutoDiffXd derivatives of the torque and stiffness outputs equal central differences at a loaded
    state, and the velocity gain is the motor PD's: d u_i / d omega_i = -Kd."""
    rig = joint_rig()
    for online in (True, False):
        law = StiffnessCorrectedImpedance(rig.params, rig.spring, online=online)
        op = rig.operating_point(pretension=20.0, joint_angle=0.1)
        x = np.asarray(op.state, float) + np.array([0.01, 0.2, 0.002, -0.001, 0.3, -0.1])
        jac = check_system_autodiff_matches_fd(
            law, [], {"state": x, "joint_angle_reference": [0.05], "effective_stiffness_reference": [0.8]}, rtol=1e-6)
        J_u, _ = jac["motor_torque"]
        kd = law.motor_gains[1]
        np.testing.assert_allclose(J_u[:, 4:6], -kd * np.eye(2), rtol=1e-12)


def test_effective_stiffness_held_while_loads_change_the_springs():
    """Fig 8.3: K_eff measured from the static deflection stays at 1 Nm/rad (then 0.7) under a load that
    changes K_mech; the online correction beats the gain computed from the nominal K_mech."""
    p = StiffnessCorrectionParams()
    kw = dict(loads=(0.0, 0.15), segment=0.25, targets=p.targets)
    runs = {c: stiffness_correction_run(corrected=c, **kw) for c in (True, False)}
    run = runs[True]
    for target in p.targets:
        seg = np.nonzero(run.k_target == target)[0]
        unloaded_end = seg[run.tau_ext[seg] == 0.0][-1]
        loaded = seg[run.tau_ext[seg] > 0]
        end = loaded[-1]
        assert abs(run.k_mech[end] - run.k_mech[unloaded_end]) > 0.002       # the load changed the springs
        err = {c: abs(r.tau_ext[end] / r.q[end] / target - 1.0) for c, r in runs.items()}
        assert err[True] < 0.02 and err[True] < err[False]
        assert np.all(run.k_imp > 0)
    fig, ax = run.plot()                                     # Fig 8.3: K_imp, K_mech, K_eff and the target
    np.testing.assert_array_equal(np.array([ln.get_ydata() for ln in ax.get_lines()]),
                                  [run.k_imp, run.k_mech, run.k_eff, run.k_target])
    import matplotlib.pyplot as plt
    plt.close(fig)


def test_stiffness_correction_closes_through_closed_loop():
    """The ch. 8 loop is built by closed_loop: ``effective_stiffness_reference`` is accepted because the
    controller reports ``effective_stiffness`` (the rig cannot measure it) and is not a tracked rig output;
    at the (8.2) operating point with the target equal to that K_mech / eps the reported K_eff is the target
    only when K_imp = (1/K_eff - 1/K_mech)^-1 (8.1), i.e. K_imp = K_eff eps / (eps - 1)."""
    from awiwi_drake.control import closed_loop
    rig = joint_rig()
    p = StiffnessCorrectionParams()
    loop = closed_loop(rig, StiffnessCorrectedImpedance(rig.params, rig.spring, p), rate_hz=None)
    assert set(loop.references) == {"joint_angle_reference", "effective_stiffness_reference"}
    assert loop.tracked_outputs == ("joint_angle",)
    target = p.targets[0]
    rq = rig.params.link_pulley_radius
    x_c = pretension_elongation(rig.spring, p.epsilon * target, rq)
    op = rig.operating_point(pretension=float(rig.spring.force(np.array([x_c]))[0]))
    ctx = loop.create_context(state=op.state, references={"effective_stiffness_reference": target})
    k_imp, k_mech, _ = loop.diagram.GetOutputPort("controller_stiffness").Eval(ctx)
    assert k_mech == pytest.approx(p.epsilon * target, rel=1e-9)              # (8.2) pretension
    assert k_imp == pytest.approx(target * p.epsilon / (p.epsilon - 1.0), rel=1e-9)
    k_eff = loop.diagram.GetOutputPort("controller_effective_stiffness").Eval(ctx)[0]
    assert k_eff == pytest.approx(target, rel=1e-9)
