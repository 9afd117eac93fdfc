"""Finger and hand diagrams: equilibria, Linearize vs the stiffness map, backends, wrist, control."""

from __future__ import annotations

import numpy as np
from _fd import check_system_autodiff_matches_fd
import pytest

from awiwi_drake.analysis.linear import linearize
from awiwi_drake.components.friction import guide_friction_force
from awiwi_drake.hand.coupling import finger_coupling
from awiwi_drake.hand.diagrams import finger_diagram, hand_diagram
from awiwi_drake.hand.wrist import wrist_tendon_offsets
from awiwi_drake.hand.systems import tendon_bending_angles
from awiwi_drake.analysis import poles_vs_pretension
from awiwi_drake.reproductions.ch05_fingers import coupling_hold_study
from awiwi_drake.reproductions.ch06_wrist import wrist_compensation_study
from awiwi_drake.parameters.hand import FINGERS, TENDON_SLICES, FingerRigParams, JointControllerParams

OPS = {"index": [0.1, 0.4, 0.3, 0.2], "middle": [0.0, 0.2, 0.5, 0.1], "ring": [0.05, 0.3, 0.4],
       "fifth": [0.1, 0.0, 0.3, 0.5], "thumb": [0.4, -0.3, 0.2, 0.3]}


def _mass_matrix(rig, q):
    ctx = rig.plant.CreateDefaultContext()
    rig.plant.SetPositions(ctx, q)
    return rig.plant.CalcMassMatrix(ctx)


@pytest.mark.parametrize("finger", FINGERS)
def test_operating_point_is_an_equilibrium_and_linearization_gives_the_stiffness_map(finger):
    rig = finger_diagram(finger=finger)     # default: compiled drive, thesis physics on
    op = rig.operating_point(pretension=25.0, joint_angles=OPS[finger])
    lin = linearize(rig, op, equilibrium_tolerance=1e-6)     # Drake checks xdot(op) ~ 0
    n = rig.num_joints
    q = op.joint_angle
    # link rows: M qdd = -K_q dq + ...  =>  M A[v, q] = -K_q  with K_q of (5.12) (+ coupling element)
    K_from_drake = -_mass_matrix(rig, q) @ lin.A[n:2 * n, :n]
    np.testing.assert_allclose(K_from_drake, op.joint_stiffness, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(op.tendon_force.mean(), 25.0, rtol=1e-12)
    assert np.all(op.tendon_force > 0)
    # without the hysteresis and guide friction states the linearisation is the leading block (at z = g = 0 and
    # rest those states enter the plant and motor rows only through their own columns)
    p = FingerRigParams.for_finger(finger).with_physics(hysteresis=False, guide_friction=False)
    ref = linearize(finger_diagram(finger=finger, params=p), _drop_z(rig, op))
    k = ref.A.shape[0]
    np.testing.assert_allclose(lin.A[:k, :k], ref.A, rtol=1e-7, atol=1e-6 * np.abs(ref.A).max())


def _drop_z(rig, op):
    """The operating point without the hysteresis and guide friction states (0 there)."""
    import dataclasses
    k = 2 * rig.num_joints + 2 * rig.num_tendons
    assert np.all(op.state[k:] == 0.0)
    return dataclasses.replace(op, state=op.state[:k])


def test_stiffest_link_mode_rises_with_pretension():
    """The lever springs stiffen with force (Fig 4.8b), so co-contraction stiffens the finger.

    Motor ripple off: its detent slope a_m N = 5.4 N m/rad (3.5) exceeds a held motor's spring
    r_m^2 k_t, so with constant motor torques the ripple alone puts a real pole at +0.94 1/s (80 N);
    the open-loop stability claim is about the springs, hysteresis and guide friction."""
    p = FingerRigParams.for_finger("index").with_physics(ripple=False)
    sweep = poles_vs_pretension(finger_diagram(finger="index", params=p), [5.0, 20.0, 80.0])
    w = sweep.max_frequency()
    assert np.all(np.diff(w) > 0)
    assert np.all(sweep.poles.real <= 1e-9)       # open loop: no unstable pole


def test_hand_is_five_decoupled_fingers_in_the_global_tendon_order():
    hand = hand_diagram(wrist=False)
    # 21 joints (q, v), 38 tendons (motor angle and velocity, hysteresis and guide friction forces)
    assert (hand.num_joints, hand.num_tendons, hand.num_states) == (21, 38, 2 * 21 + 4 * 38)
    assert hand.tendon_names[TENDON_SLICES["ring"]][0] == "ring_h1"
    lin_h = linearize(hand, hand.operating_point())
    index = finger_diagram(finger="index")
    lin_i = linearize(index, index.operating_point())
    hj = [hand.state_names.index(s) for s in index.state_names]
    np.testing.assert_allclose(lin_h.A[np.ix_(hj, hj)], lin_i.A, rtol=1e-9, atol=1e-9)
    others = np.setdiff1d(np.arange(hand.num_states), hj)
    assert not np.any(lin_h.A[np.ix_(hj, others)])


def test_wrist_offsets_enter_the_equilibrium():
    rig = finger_diagram(finger="index", wrist=True)
    op0 = rig.operating_point()
    op = rig.operating_point(wrist_angle=[np.radians(10.0), np.radians(-5.0)])
    linearize(rig, op, equilibrium_tolerance=1e-6)
    off = wrist_tendon_offsets(np.radians(10.0), np.radians(-5.0))[TENDON_SLICES["index"]]
    n = rig.num_joints
    dtheta = op.state[2 * n:2 * n + 8] - op0.state[2 * n:2 * n + 8]
    np.testing.assert_allclose(dtheta, -off / rig.params.motor.pulley_radius, rtol=1e-12, atol=1e-15)


def test_wrist_feedforward_reduces_finger_drift_down_to_the_friction_limit():
    """5 deg wrist abduction sweep, index under the 3 kHz motor PD: the feedforward -h_wrist/r_m
    removes the tendon path change (6.9); what remains is the friction-limited motor PD
    u = kp (theta_ref - theta) - kd omega following the moving reference: each motor lags it by at most
    (gamma2 + (kd + gamma3) |omega| + B |omega'|) / kp + |omega| T / 2 (Coulomb and viscous torque (3.8), the
    PD's absolute-velocity damping, the inertia, half a 3 kHz period of zero-order hold), omega = h_wrist' /
    r_m at the sweep's peak rate, i.e. r_m times that of tendon, which the routing maps to at most |P^+| of it
    per joint (abduction: 6.8e-3 rad; the static part r_m gamma2/kp alone is 4.65e-3 rad, measured 4.55e-3).
    Without the spring hysteresis: its force is not seen by the motor PD
    and adds its own offset K_q^-1 P^T z (measured with it: abduction 5.1e-3 rad, 1.1x the friction
    bound). Without the guide friction for the same reason: its forces g (|g_i| <= C_i ~ 2 N, (4.1)) add
    K_q^-1 P^T g."""
    no_hysteresis = FingerRigParams.for_finger("index").with_physics(hysteresis=False, guide_friction=False)
    s = wrist_compensation_study("index", amplitude=np.radians(5.0), frequency=0.5, t_final=0.4,
                                 params=no_hysteresis)
    mp, c = FingerRigParams.for_finger("index").motor, JointControllerParams()
    amp, w, h = np.radians(5.0), 2 * np.pi * 0.5, 1e-6       # the sweep: amp sin(w t)
    angles = np.linspace(-amp, amp, 41)
    offset = lambda a: wrist_tendon_offsets(a, 0.0)[TENDON_SLICES["index"]]  # noqa: E731
    d1 = np.max([np.abs(offset(a + h) - offset(a - h)) / (2 * h) for a in angles], axis=0)
    d2 = np.max([np.abs(offset(a + h) - 2 * offset(a) + offset(a - h)) / h ** 2 for a in angles], axis=0)
    omega = d1 * amp * w / mp.pulley_radius                               # rad/s, motor
    omega_dot = (d1 * amp * w ** 2 + d2 * (amp * w) ** 2) / mp.pulley_radius
    lag = ((mp.coulomb_torque + (c.kd + mp.viscous_friction) * omega + mp.inertia * omega_dot) / c.kp
           + omega * c.period / 2)
    bound = np.abs(np.linalg.pinv(finger_coupling("index").P())) @ (mp.pulley_radius * lag)
    assert np.all(np.abs(s.drift_compensated).max(axis=0) <= bound)
    assert np.abs(s.drift_uncompensated).max(axis=0)[0] > 5 * bound[0]     # without it: far beyond friction
    assert s.min_tendon_force["compensated"] > s.min_tendon_force["uncompensated"]
    assert not [e for e in s.events["compensated"] if e.kind == "tendon_slack"]


def test_large_uncompensated_wrist_motion_slackens_tendons_and_is_reported():
    # without the spring hysteresis and guide friction (as above): the slack threshold is about the elastic path change
    s = wrist_compensation_study("index", amplitude=np.radians(15.0), frequency=0.5, t_final=0.45,
                                 params=FingerRigParams.for_finger("index").with_physics(hysteresis=False,
                                                                                         guide_friction=False))
    slack = [e for e in s.events["uncompensated"] if e.kind == "tendon_slack"]
    assert slack and s.min_tendon_force["uncompensated"] == 0.0
    assert s.min_tendon_force["compensated"] > 10.0


def test_joint_control_reaches_the_reference_and_keeps_the_coupling():
    """Ring PIP step of 0.5 rad under the 3 kHz joint PD.  The coupling: during the step the pair's force change
    (< 10 N) puts at most r43 * 10 N = 0.05 N m on the DIP; the coupling compliance 1/(k_c (1 + c^2)) = 0.166
    rad/N m turns it into 8.3e-3 rad (measured 2.3e-3 rad).

    The PIP's end error, against the statics of Drake's ``Linearize`` of the continuous loop (the sampled law at
    rest is the continuous one) at the end state, with the spring hysteresis and guide friction states frozen
    (their presliding holds them at rest): the loop's rest without those forces (the motor PD's compliance), plus
    their reach ``sum_i |(A_rr^-1 A_rf)_pip,i| |x_f,i|`` with the states the run ends with (3.0e-3 rad; the states
    at their bounds reach further), plus the way still to go to that rest (``A_rr^-1 f_r``, 2.7e-3 rad: the run is
    0.25 s).  First order; measured end error 3.9e-4 rad, the loop's rest without the friction 1.2e-4 rad."""
    from pydrake.systems.primitives import Linearize
    from awiwi_drake.control import closed_loop
    from awiwi_drake.control.joint_pd import joint_pd_controller
    s = coupling_hold_study("ring", pip_step=0.5, t_final=0.25)
    fp = FingerRigParams.for_finger("ring").finger
    bound = fp.dip_radius * 10.0 / (fp.coupling_stiffness * (1 + fp.dip_pip_ratio ** 2))
    assert s.max_coupling_error < bound
    rig = finger_diagram(finger="ring")
    n = rig.num_joints
    q_ref = np.zeros(n)
    q_ref[n - 2], q_ref[n - 1] = 0.5, 0.5 * fp.dip_pip_ratio
    loop = closed_loop(rig, joint_pd_controller(rig), rate_hz=None)
    d = loop.diagram
    ctx = loop.create_context(rig.operating_point(), references={"joint_angle_reference": q_ref})
    ctx.SetContinuousState(s.final_state)
    A = Linearize(d, ctx, input_port_index=d.GetInputPort("joint_angle_reference").get_index(),
                  output_port_index=d.GetOutputPort("joint_angle").get_index(), equilibrium_check_tolerance=np.inf).A()
    fr = [i for i, nm in enumerate(rig.state_names) if nm.startswith(("hysteresis_force", "guide_friction_force"))]
    rr = [i for i in range(len(rig.state_names)) if i not in fr]
    pip = rr.index(n - 2)                                     # the PIP's angle among the regular states
    Arr = A[np.ix_(rr, rr)]
    to_go = -np.linalg.solve(Arr, d.EvalTimeDerivatives(ctx).CopyToVector()[rr])[pip]
    reach = np.abs(np.linalg.solve(Arr, A[np.ix_(rr, fr)])[pip]) @ np.abs(s.final_state[fr])
    free = s.final_state.copy()
    free[fr] = 0.0                                            # the same state without the friction forces
    ctx.SetContinuousState(free)
    rest_free = free[n - 2] - np.linalg.solve(Arr, d.EvalTimeDerivatives(ctx).CopyToVector()[rr])[pip] - 0.5
    assert reach > 0.0 and np.abs(s.final_state[fr]).max() > 0.01          # the friction states do act
    assert abs(s.q_pip[-1] - 0.5) <= abs(rest_free) + reach + abs(to_go)
    fig, ax = s.plot()
    np.testing.assert_array_equal(ax.get_lines()[2].get_ydata(), s.coupling_error)
    import matplotlib.pyplot as plt
    plt.close(fig)


def test_tendon_bending_angles_follow_the_routing():
    p = FingerRigParams.for_finger("index")
    alpha = tendon_bending_angles(finger_coupling("index"), p)
    assert alpha[0] == pytest.approx(p.palm_bending_angle + 2 * p.joint_wrap_angle)   # abd + MCP
    P0 = np.asarray(finger_coupling("index").P(np.zeros(4)))
    np.testing.assert_allclose(alpha, p.palm_bending_angle + p.joint_wrap_angle * (np.abs(P0) > 0).sum(axis=1))


def test_guide_friction_and_hysteresis_at_rest_linearise_to_presliding_springs_not_dampers():
    """At rest the Dahl states are springs on the tendon path (the guides and the lever hold the
    tendon): Drake's linearisation gives dg/dt = (C/delta_g) P v, dz/dt = (w/delta)(r_m omega + P v),
    and no damping (d(dg)/dg = d(dz)/dz = 0). A regularised sign tanh(v/v_s) would instead add the
    damping C/v_s = 2000 N s/m per tendon that overdamps the light links (and puts h lambda at -536)."""
    rig = finger_diagram(finger="index", params=FingerRigParams.for_finger("index").with_physics(guide_friction=True))
    p = rig.params
    n, m = rig.num_joints, rig.num_tendons
    op = rig.operating_point()
    A = linearize(rig, op).A
    P = np.asarray(rig.coupling.P(op.joint_angle))
    v, om = slice(n, 2 * n), slice(2 * n + m, 2 * n + 2 * m)
    z, g = slice(2 * n + 2 * m, 2 * n + 3 * m), slice(2 * n + 3 * m, 2 * n + 4 * m)
    C = guide_friction_force(tendon_bending_angles(rig.coupling, p), p.friction)
    np.testing.assert_allclose(A[g, v], (C / p.guide_presliding_length)[:, None] * P, rtol=1e-9)
    w = p.spring.hysteresis.width_ratio * op.tendon_force
    np.testing.assert_allclose(A[z, v], (w / p.spring.hysteresis.presliding_length)[:, None] * P, rtol=1e-9)
    np.testing.assert_allclose(np.diag(A[z, om]), w / p.spring.hysteresis.presliding_length * p.motor.pulley_radius,
                               rtol=1e-9)
    assert not np.any(A[g, g]) and not np.any(A[z, z])
    Minv = np.linalg.inv(_mass_matrix(rig, op.joint_angle))
    np.testing.assert_allclose(A[v, g], -Minv @ P.T, rtol=1e-9, atol=1e-12 * np.abs(Minv).max())


def test_bad_operating_points_raise_named_errors():
    rig = finger_diagram(finger="ring")
    with pytest.raises(ValueError, match="joint_angles"):
        rig.operating_point(joint_angles=[0.0, 0.1])
    with pytest.raises(ValueError, match="slack"):
        rig.operating_point(pretension=1.0, external_torque=[0.0, 0.5, 0.0, 0.0])
    with pytest.raises(ValueError, match="wrist"):
        rig.operating_point(wrist_angle=[0.1, 0.0])
    with pytest.raises(ValueError, match="finger"):
        finger_diagram(finger="pinky")
    with pytest.raises(ValueError, match="finger_name"):
        finger_diagram(finger="ring", params=FingerRigParams.for_finger("index"))
    with pytest.raises(ValueError, match="FingerRigParams.finger must be ThumbParams"):
        FingerRigParams(finger_name="thumb")


def test_hand_simulates_under_joint_control():
    """The whole hand with the 3 kHz controller is its fingers side by side (decoupled routing, palm
    fixed, wrist at 0): the commanded index joints follow exactly the trajectory of the index finger rig
    built and closed on its own (same controller, integrator and step; equal to round-off, 1e-12 rad),
    the other fingers stay put, no tendon goes slack."""
    from awiwi_drake.analysis import rig_monitors, simulate
    from awiwi_drake.control import closed_loop, make_controller

    def run(rig, q_ref):
        cl = closed_loop(rig, make_controller("joint-pd", rig))
        ctx = cl.create_context(rig.operating_point(), references={"joint_angle_reference": q_ref})
        return simulate(cl.diagram, ctx, 0.06, log=("joint_angle", "tendon_force"), monitors=rig_monitors(rig),
                        max_step=1.0 / 3000, accuracy=1e-3)
    hand, finger = hand_diagram(), finger_diagram(finger="index")
    q_ref = np.zeros(hand.num_joints)
    q_ref[hand.joint_names.index("q21")] = 0.2
    idx = [hand.joint_names.index(n) for n in finger.joint_names]
    res, alone = run(hand, q_ref), run(finger, q_ref[idx])
    np.testing.assert_array_equal(res.t, alone.t)
    np.testing.assert_allclose(res["joint_angle"][:, idx], alone["joint_angle"], rtol=0, atol=1e-12)
    assert abs(alone["joint_angle"][-1, 1]) > 0.1 * 0.2        # the MCP moved (the comparison is not 0 = 0)
    others = [i for i in range(hand.num_joints) if i not in idx]
    assert np.max(np.abs(res["joint_angle"][:, others])) < 1e-9
    assert not [e for e in res.events if e.kind == "tendon_slack"]


def test_routing_system_with_the_thumb_coupling_converts_to_autodiff():
    from awiwi_drake.components.routing import TendonRouting_
    sys = TendonRouting_[float](finger_coupling("thumb"), 0.005, np.full(8, 1e-3))
    rng = np.random.default_rng(5)
    theta, q, f = rng.uniform(-1, 1, 8), rng.uniform(-1, 1, 4), rng.uniform(5, 40, 8)
    jac = check_system_autodiff_matches_fd(sys, [], {"motor_angle": theta, "joint_angle": q, "tendon_force": f},
                                           outputs=["elongation", "generalized_force"], rtol=1e-6)
    # x = r_m theta + h(q) - h(0) + x0 and tau = -P(q)^T f: d x/d theta = r_m I, d x/d q = P(q), d tau/d f = -P(q)^T
    P = np.asarray(finger_coupling("thumb").P(q), float)
    J_x, J_tau = jac["elongation"][0], jac["generalized_force"][0]
    np.testing.assert_allclose(J_x[:, :8], 0.005 * np.eye(8), atol=1e-12)
    np.testing.assert_allclose(J_x[:, 8:12], P, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(J_tau[:, 12:], -P.T, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("finger", ["thumb", "ring"])
def test_estimated_joint_angles_track_the_plant_in_closed_loop(finger):
    """No joint sensors: the 3 kHz estimator (motor angles + spring elongations) follows the plant."""
    from awiwi_drake.analysis.simulate import simulate
    from awiwi_drake.control import closed_loop, make_controller
    rig = finger_diagram(finger=finger)
    cl = closed_loop(rig, make_controller("joint-pd", rig), estimator=rig.link_estimator())
    q_ref = np.asarray(OPS[finger + "_ref"] if finger + "_ref" in OPS else
                       rig.coupling.dof_selection @ np.array(OPS[finger]), float)
    res = simulate(cl.diagram, cl.create_context(rig.operating_point(), references={"joint_angle_reference": q_ref}),
                   0.1,
                   log=("joint_angle", "joint_angle_estimate", "joint_velocity"), max_step=1.0 / 3000,
                   accuracy=1e-3)
    late = res.t > 0.05
    err = np.abs(res["joint_angle_estimate"][late] - res["joint_angle"][late]).max(axis=0)
    # bound: one sample of lag (|v| * period) + the search tolerance (thumb, 15 warm-started
    # iterations: < 1e-4 rad) + for the ring PIP/DIP the coupling element's deflection e (the DIP is
    # estimated as c q_PIP; the PIP absorbs r43 e / (r42 + c r43) of it; |e| < 5e-3 rad here)
    lag = np.abs(res["joint_velocity"][late]).max(axis=0) / 3000
    extra = np.full(rig.num_joints, 1e-4)
    if finger == "ring":
        extra[-2:] = 5e-3
    assert np.all(err <= lag + extra), (err, lag)
    assert np.linalg.norm(res["joint_angle"][-1] - q_ref) < 0.5 * np.linalg.norm(q_ref)   # it moved


def test_gravity_option_keeps_the_operating_point_an_equilibrium():
    """With gravity on, the operating point's tendon forces change by exactly what holds the links up:
    ``P(q)^T (f_g - f_0) = tau_g(q)``, the gravity generalised force from MultibodyPlant; its size is the
    0.002-0.008 Nm of section 5.2.2."""
    q = np.array([0.0, 0.5, 0.3, 0.2])
    p = FingerRigParams.for_finger("index", gravity=True)
    rig = finger_diagram(finger="index", params=p)
    op = rig.operating_point(joint_angles=q)
    linearize(rig, op, equilibrium_tolerance=1e-6)
    op0 = finger_diagram(finger="index").operating_point(joint_angles=q)
    plant_ctx = rig.plant.CreateDefaultContext()
    rig.plant.SetPositions(plant_ctx, q)
    tau_g = rig.plant.CalcGravityGeneralizedForces(plant_ctx)
    P = np.asarray(finger_coupling("index").P(q))
    np.testing.assert_allclose(P.T @ (op.tendon_force - op0.tendon_force), tau_g,
                               rtol=1e-9, atol=1e-12)
    assert 0.002 <= np.max(np.abs(tau_g)) <= 0.008


def test_thumb_base_reaches_a_large_reference_through_the_exact_routing():
    """A 0.5/0.35 rad thumb-base step under joint PD ends at the static equilibrium of the exact routing,
    solved here without the simulator: the motors hold theta_ref (compliance r_m/kp in series), the springs
    sit at the operating elongation plus h(q) - h(q_ref), and P(q)^T f(x) = 0.  The equilibrium is not
    q_ref (P(q_ref)^T f_op != 0 for the nonlinear base)."""
    from scipy.optimize import fsolve
    from awiwi_drake.analysis import rig_monitors, simulate
    from awiwi_drake.control import closed_loop, make_controller
    rig = finger_diagram(finger="thumb")
    op, c, law = rig.operating_point(), rig.coupling, rig.spring
    cl = closed_loop(rig, make_controller("joint-pd", rig))
    q_ref = np.array([0.5, 0.35, 0.0, 0.0])
    res = simulate(cl.diagram, cl.create_context(op, references={"joint_angle_reference": q_ref}),
                   0.5, log=("joint_angle",), monitors=rig_monitors(rig), max_step=1.0 / 3000, accuracy=1e-3)
    assert not [e for e in res.events if e.kind == "tendon_slack"]
    r_m, kp, tau_c = rig.params.motor.pulley_radius, JointControllerParams().kp, rig.params.motor.coulomb_torque
    f_op, x_op = np.asarray(op.tendon_force), np.asarray(op.elongation)

    def balance(z):
        q, f = z[:4], z[4:]
        x = x_op + c.h(q) - c.h(q_ref) - r_m ** 2 * (f - f_op) / kp
        return np.r_[c.P(q).T @ f, f - np.asarray(law.force(x), float)]
    z = fsolve(balance, np.r_[q_ref, f_op], xtol=1e-13)
    assert np.max(np.abs(balance(z))) < 1e-9
    q_eq = z[:4]
    assert np.max(np.abs(q_eq - q_ref)[:2]) > 0.01                      # the base does not reach q_ref
    # band: motor Coulomb friction lets each motor stick up to tau_c / kp off theta_ref, i.e. r_m tau_c / kp
    # of tendon; through the joint stiffness that moves q by at most |K^-1 P^T diag(k_t)| r_m tau_c / kp
    op_eq = rig.operating_point(joint_angles=q_eq)
    K, k_t = np.asarray(op_eq.joint_stiffness), np.asarray(op_eq.tendon_stiffness)
    band = np.abs(np.linalg.solve(K, c.P(q_eq).T @ np.diag(k_t))).sum(axis=1) * r_m * tau_c / kp
    # plus the spring hysteresis (on by default): the lever's Dahl force |z_i| <= w_i = beta f_i + z0 adds to
    # each tendon force, which moves q by at most |K^-1 P^T| w (about 5x the friction band here)
    hyst = rig.params.spring.hysteresis
    if hyst.enabled:
        band = band + np.abs(np.linalg.solve(K, c.P(q_eq).T)) @ (hyst.width_ratio * z[4:] + hyst.width_offset)
    late = res.t >= 0.25                                                 # the base settles within 0.2 s
    assert np.all(np.abs(res["joint_angle"][late].mean(axis=0) - q_eq) < band), (q_eq, band)
