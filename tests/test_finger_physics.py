"""The thesis's physics in the finger and hand plant, on by default (issue 10 item 4).

Each effect is checked as physics: its closed-form contribution to the state derivative
(motor friction (3.8), ripple (3.5), spring hysteresis Fig 4.8b, guide friction (4.1)), the
ideal plant when every switch is off, passivity of the two Dahl states over closed cycles,
and stability of fixed-step RK3 at the 3 kHz control period from the eigenvalues of Drake's
linearisation times h.
"""

from __future__ import annotations

import numpy as np
import pytest

from awiwi_drake.analysis import linearize
from _finger_laws import compiled, ideal_drive_derivatives
from awiwi_drake.components.friction import dahl_rate, guide_friction_force, guide_friction_rate
from awiwi_drake.hand.diagrams import finger_diagram, hand_diagram
from awiwi_drake.hand.systems import tendon_bending_angles
from awiwi_drake.parameters.hand import FingerRigParams, HandRigParams

H = 1.0 / 3000.0          # the control period: fixed-step RK3 integrates sampled loops at it
IDEAL = dict(ripple=False, hysteresis=False, guide_friction=False, motor_friction=False)
RNG = np.random.default_rng(11)


def rk3_growth(h_lambda):
    """|R(h lambda)| of every explicit 3-stage, 3rd-order Runge-Kutta method (Drake's RK3)."""
    z = np.asarray(h_lambda)
    return np.abs(1 + z + z ** 2 / 2 + z ** 3 / 6)


def rk3_excess_growth(A, h=H):
    """max over the eigenvalues of A of |R(h lambda)| - max(1, |exp(h lambda)|): > 0 where the
    integrator amplifies a mode that the continuous system does not (numerical instability)."""
    ev = np.linalg.eigvals(A)
    return float(np.max(rk3_growth(h * ev) - np.maximum(1.0, np.abs(np.exp(h * ev)))))


def test_the_finger_plant_has_the_thesis_physics_on_by_default():
    p = FingerRigParams.for_finger("index")
    assert p.motor.friction and p.motor.ripple and p.spring.hysteresis.enabled and p.guide_friction
    assert p.spring.include_tendon                               # k_t = E S / l0 in series
    assert not p.with_physics(guide_friction=False).guide_friction
    rig = finger_diagram(finger="index", params=p)
    n, m = rig.num_joints, rig.num_tendons
    assert rig.num_states == 2 * n + 4 * m
    assert rig.state_names[2 * n + 2 * m] == f"hysteresis_force[{rig.tendon_names[0]}]"
    assert rig.state_names[-1] == f"guide_friction_force[{rig.tendon_names[-1]}]"
    hand = HandRigParams()
    assert hand.motor.ripple and hand.spring.hysteresis.enabled and hand.guide_friction
    # the joints' stick-slip is off by default (no thesis level); switched on it adds one state per joint, last
    assert not p.joint_friction and not hand.joint_friction
    assert p.with_physics(joint_friction=True).joint_friction
    on = finger_diagram(finger="index", params=p.with_physics(joint_friction=True))
    assert on.num_states == 2 * n + 4 * m + n and on.state_names[-1] == "joint_friction_torque[q23]"
    # per joint: an override changes that joint's row only; an unknown joint is one line naming it
    from awiwi_drake.parameters.components import JointFrictionParams
    own = JointFrictionParams(coulomb=0.02, static=0.03)
    one = finger_diagram(finger="index", params=p.with_physics(joint_friction=True).replace(joint_frictions=(("q22", own),)))
    rows = one.diagram.GetSubsystemByName("hand_dynamics").links.joint_friction
    base = on.diagram.GetSubsystemByName("hand_dynamics").links.joint_friction
    np.testing.assert_array_equal(rows[[0, 1, 3]], base[[0, 1, 3]])
    assert tuple(rows[2]) == (0.02, 0.03, own.stribeck_velocity, own.presliding_angle) != tuple(base[2])
    with pytest.raises(ValueError, match="joint_frictions: unknown joint 'q99'; joints are q20, q21, q22, q23"):
        finger_diagram(finger="index", params=p.replace(joint_friction=True, joint_frictions=(("q99", own),)))
    with pytest.raises(ValueError, match="JointFrictionParams.static = 0.005 Nm must be >= coulomb"):
        JointFrictionParams(static=0.005)


def _mass_matrix(rig, q):
    ctx = rig.plant.CreateDefaultContext()
    rig.plant.SetPositions(ctx, q)
    return rig.plant.CalcMassMatrix(ctx)


@pytest.mark.parametrize("finger", ["index", "thumb"])
def test_each_effect_adds_its_closed_form_and_all_off_is_the_ideal_plant(finger):
    """At random states: (on) - (ideal) derivatives = motor friction (3.8) + ripple (3.5) on the
    rotor, the hysteresis force z on spring and rotor, the guide friction g on the joints only, and
    the two Dahl rates in closed form, and the joints' stick-slip torque tau_f on the joints with its presliding rate
    ``-(Fs/delta)(v + |v| tau_f / W(v))``, W the Stribeck curve. The ideal plant equals the laws evaluated apart to 1e-9: the standalone
    MultibodyPlant (``rig.plant``) under ``-P(q)^T f(x)``, ``x = r_m theta + h(q) - h(0) + x0``, the motors'
    (3.5) with load ``r_m f``.  On the index the plant with every effect runs on its compiled kernels (the thumb on
    the generic path), so the closed forms check both."""
    p_on = FingerRigParams.for_finger(finger).with_physics(guide_friction=True, joint_friction=True)
    on, off = finger_diagram(finger=finger, params=p_on), finger_diagram(finger=finger,
                                                                          params=p_on.with_physics(**IDEAL, joint_friction=False))
    jp = p_on.joint_friction_params
    if finger == "index":   # on the compiled kernels, so that their joint-friction terms are checked too
        compiled(on)
    n, m = on.num_joints, on.num_tendons
    mp, hp, gp = p_on.motor, p_on.spring.hysteresis, p_on
    alpha = tendon_bending_angles(on.coupling, p_on)
    C = guide_friction_force(alpha, p_on.friction)
    op = on.operating_point()
    r_m, B = mp.pulley_radius, mp.inertia
    for _ in range(3):
        q = op.joint_angle + RNG.uniform(-0.03, 0.03, n)
        v = RNG.normal(scale=0.5, size=n)
        theta = op.state[2 * n:2 * n + m] + RNG.uniform(-0.01, 0.01, m)
        omega = RNG.normal(scale=2.0, size=m)
        z = RNG.uniform(-1.5, 1.5, m)
        g = RNG.uniform(-1.5, 1.5, m)
        u = op.motor_torque + RNG.normal(scale=0.05, size=m)
        tau_f = RNG.uniform(-jp.static, jp.static, n)
        x_off = np.concatenate([q, v, theta, omega])
        derivs = []
        for rig, x in ((on, np.concatenate([x_off, z, g, tau_f])), (off, x_off)):
            ctx = rig.context(rig.operating_point())
            ctx.SetContinuousState(x)
            rig.diagram.GetInputPort("motor_torque").FixValue(ctx, u)
            derivs.append(rig.diagram.EvalTimeDerivatives(ctx).CopyToVector())
            if rig is off:
                f_el = rig.diagram.GetOutputPort("tendon_force").Eval(ctx)      # the elastic force
        d_on, d_off = derivs
        np.testing.assert_allclose(d_off, ideal_drive_derivatives(off, q, v, theta, omega, u), rtol=1e-9, atol=1e-9)
        assert np.all(f_el + z > 0)                                               # no slack in this check
        P = np.asarray(on.coupling.P(q))
        dv = np.linalg.solve(_mass_matrix(on, q), -P.T @ (z + g) + tau_f)
        fric = -(mp.coulomb_torque * np.arctan(mp.friction_slope * omega) + mp.viscous_friction * omega)
        ripple = (mp.ripple_motor_amplitude * np.sin(mp.gear_ratio * theta + mp.ripple_motor_phase)
                  + mp.ripple_output_amplitude * np.sin(theta + mp.ripple_output_phase))
        domega = (fric + ripple - r_m * z) / B
        xdot = r_m * omega + P @ v
        w = hp.width_ratio * f_el + hp.width_offset
        dz = xdot / hp.presliding_length * (w - np.tanh(xdot / hp.smoothing_velocity) * z)
        slide = P @ v
        dg = (slide * C - np.abs(slide) * g) / gp.guide_presliding_length       # Dahl's law, |v| exactly
        expected = np.concatenate([np.zeros(n), dv, np.zeros(m), domega])
        np.testing.assert_allclose(d_on[:2 * n + 2 * m] - d_off, expected, rtol=1e-7, atol=1e-7)
        np.testing.assert_allclose(d_on[2 * n + 2 * m:2 * n + 3 * m], dz, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(d_on[2 * n + 3 * m:2 * n + 4 * m], dg, rtol=1e-9, atol=1e-9)
        W = jp.coulomb + (jp.static - jp.coulomb) * np.exp(-(v / jp.stribeck_velocity) ** 2)
        dtau = -(jp.static / jp.presliding_angle) * (v + np.abs(v) * tau_f / W)
        np.testing.assert_allclose(d_on[2 * n + 4 * m:], dtau, rtol=1e-9, atol=1e-9)


def _cycle_work(rate, amplitude, F0=0.0, cycles=1, steps=4000):
    """Integrate a Dahl state along x = A sin(t) from F(0) = F0 (RK4 on a fine grid, t in
    [0, 2 pi cycles]) and return the work int F dx over the last cycle and the state there."""
    t = np.linspace(0.0, 2 * np.pi * cycles, steps * cycles + 1)
    dt = t[1] - t[0]
    F = np.full_like(t, F0)
    for k in range(t.size - 1):
        def f(tt, FF):
            return rate(FF, amplitude * np.cos(tt), amplitude * np.sin(tt))
        k1 = f(t[k], F[k])
        k2 = f(t[k] + dt / 2, F[k] + dt / 2 * k1)
        k3 = f(t[k] + dt / 2, F[k] + dt / 2 * k2)
        k4 = f(t[k] + dt, F[k] + dt * k3)
        F[k + 1] = F[k] + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    last = t >= t[-1] - 2 * np.pi
    xdot = amplitude * np.cos(t[last])
    return np.trapezoid(F[last] * xdot, t[last]), F[last]


@pytest.mark.parametrize("amplitude", [1e-4, 4e-4, 2e-3])
def test_dahl_friction_dissipates_over_every_closed_cycle_with_the_closed_form_loop(amplitude):
    """The loop integral of force x velocity of the Dahl state (hysteresis in the lever, guide
    friction in the guides) is positive, and for a constant level W equals the closed form of the
    steady loop: the state swings between +-Z, Z = W tanh(A / delta), and the dissipated work per
    cycle is 2 (2 W A - delta (W + Z) (1 - exp(-2 A / delta)))."""
    W, delta, v_s = 2.0, 4e-4, 1e-7     # v_s far below the sliding speeds: the sign is sharp
    A = amplitude
    Z = W * np.tanh(A / delta)

    def rate(F, xdot, x):
        return dahl_rate(F, xdot, W, delta, v_s)
    # start on the steady loop (x = 0, loading): the loop closes on itself if the closed form is right
    work, F = _cycle_work(rate, amplitude, F0=W - (W + Z) * np.exp(-A / delta))
    # loading branch from x = -A (F = -Z): F(x) = W - (W + Z) exp(-(x + A)/delta); by symmetry the
    # loop work is 2 int_{-A}^{A} F_load dx - 0 (the unloading branch is its mirror image)
    e = np.exp(-2 * A / delta)
    load = W * 2 * A - (W + Z) * delta * (1 - e)
    expected = 2 * load
    assert work > 0
    assert F.max() == pytest.approx(Z, rel=1e-3)
    assert work == pytest.approx(expected, rel=2e-3)
    # the guide friction with the capstan part: its level rises with the tension, still passive
    for capstan in (0.0, 0.3):
        def rate_g(Fg, xdot, x):
            return guide_friction_rate(Fg, xdot, 20.0, 1.0, capstan, delta, v_s)
        w_g, _ = _cycle_work(rate_g, amplitude)
        assert w_g > 0


def _rk3_check(rig, pretension):
    op = rig.operating_point(pretension=pretension)
    return rk3_excess_growth(linearize(rig, op).A)


@pytest.mark.parametrize("finger", ["thumb", "index", "middle", "ring", "fifth"])
def test_default_finger_physics_is_stable_for_rk3_at_the_control_period(finger):
    """Every eigenvalue of the Drake linearisation of the finger with all physics on times the
    3 kHz period lies in RK3's stability region, at the default 20 N and, with the joints' stick-slip on too, at 35 N
    pretension (the case that bounds its presliding stiffness, JointFrictionParams.presliding_angle); the
    old Dahl parameters (presliding stiffness 2e5 N/m: delta = 2 N / 2e5 N/m = 1e-5 m at 20 N) do not, nor (fifth
    finger) a joint presliding stiffness sized by its own mode alone, h^2 sigma0 lambda_max(M^-1) = 3/4 (0.88 Nm/rad),
    which ignores the plant's fastest (coupling) mode it adds to."""
    p = FingerRigParams.for_finger(finger).with_physics(guide_friction=True)
    assert _rk3_check(finger_diagram(finger=finger, params=p), 20.0) <= 1e-9, finger
    pj = p.with_physics(joint_friction=True)
    assert _rk3_check(finger_diagram(finger=finger, params=pj), 35.0) <= 1e-9, finger
    if finger == "fifth":
        jp = pj.joint_friction_params
        M_inv_max = np.linalg.eigvalsh(np.linalg.inv(_mass_matrix(finger_diagram(finger=finger), np.zeros(5)))).max()
        sigma0 = 0.75 / (H ** 2 * M_inv_max)
        too_stiff = pj.replace(joint_friction_params=jp.replace(presliding_angle=jp.static / sigma0))
        assert _rk3_check(finger_diagram(finger=finger, params=too_stiff), 35.0) > 0.05
    if finger == "index":
        old = p.replace(spring=p.spring.replace(hysteresis=p.spring.hysteresis.replace(presliding_length=1e-5)))
        assert _rk3_check(finger_diagram(finger=finger, params=old), 20.0) > 0.1


def test_default_hand_physics_is_stable_for_rk3_at_the_control_period():
    hand = hand_diagram(params=HandRigParams().with_physics(guide_friction=True))
    assert _rk3_check(hand, 20.0) <= 1e-9


def test_finger_backstepping_with_guide_friction_drops_the_link_acceleration_feedforward():
    """Why the 15.5 finger law does not feed its link model's acceleration forward by default (Drake's Linearize of
    the continuous loop, true joint state, index with guide friction on): with it (the exact design, motor friction
    cancelled in full) the guides' presliding stiffness, which the link model lacks, gives a real pole far in the
    right half plane (measured +833 1/s); without it every pole has Re <= 0 (the Dahl states are marginal)."""
    from pydrake.systems.primitives import Linearize
    from awiwi_drake.control import closed_loop
    from awiwi_drake.control.base import StaticLawController
    from awiwi_drake.control.finger_backstepping import FingerBacksteppingLaw
    from awiwi_drake.parameters.hand_control import HandChainParams

    def max_real(params):
        rig = finger_diagram(finger="index")
        assert rig.params.guide_friction                                  # on by default
        loop = closed_loop(rig, StaticLawController(FingerBacksteppingLaw(rig, params)), rate_hz=None,
                           sensors="ideal")
        op = rig.operating_point()
        ctx = loop.create_context(op, references={"joint_angle_reference": op.joint_angle})
        A = Linearize(loop.diagram, ctx, input_port_index=loop.diagram.GetInputPort("joint_angle_reference").get_index(),
                      output_port_index=loop.diagram.GetOutputPort("joint_angle").get_index()).A()
        return np.linalg.eigvals(A).real.max()

    assert max_real(HandChainParams(backstepping_friction_scale=1.0, link_acceleration_feedforward=True)) > 500.0
    assert max_real(HandChainParams()) <= 1e-6


def test_fixed_step_rk3_at_the_control_period_follows_the_error_controlled_solution():
    """The index finger with all the physics on (guide friction too) under the 3 kHz joint PD, a 0.3 rad MCP
    step: the default fixed-step RK3 at the control period stays finite and equals an error-controlled run
    (RK3, accuracy 1e-6) within 1 % of the step; the Dahl states do move (the loop is not trivially at rest)."""
    from awiwi_drake.analysis import simulate
    from awiwi_drake.control import closed_loop, make_controller
    p = FingerRigParams.for_finger("index").with_physics(guide_friction=True)
    out = {}
    for mode in ("fixed_step", "error_controlled"):
        rig = finger_diagram(finger="index", params=p)
        loop = closed_loop(rig, make_controller("joint-pd", rig))
        op = rig.operating_point()
        ref = op.joint_angle.copy()
        ref[1] += 0.3
        ctx = loop.create_context(op, references={"joint_angle_reference": ref})
        kw = dict(accuracy=1e-6, max_step=H) if mode == "error_controlled" else {}
        res = simulate(loop.diagram, ctx, 0.15, log=("joint_angle", "state"), mode=mode, log_period=H, **kw)
        out[mode] = res
    a, b = out["fixed_step"], out["error_controlled"]
    assert np.all(np.isfinite(a["state"]))
    n = min(len(a.t), len(b.t))
    assert np.max(np.abs(a["joint_angle"][:n] - b["joint_angle"][:n])) < 0.01 * 0.3
    n_j, m = 4, 8
    z = a["state"][:, 2 * n_j + 2 * m:2 * n_j + 3 * m]
    g = a["state"][:, 2 * n_j + 3 * m:]
    assert np.abs(z).max() > 0.1 and np.abs(g).max() > 0.1          # [N]: hysteresis and guide friction act


def test_the_memoryless_stribeck_law_needs_a_sign_smoothing_above_the_rk3_bound_at_the_control_period():
    """Why the plant's joint friction is a presliding state: the memoryless :func:`stribeck_friction` linearises at
    rest to the damping Fs / v_eps, so fixed-step RK3 at the 3 kHz period on a joint of effective inertia
    1 / (M^-1)_jj is stable only for v_eps >= h Fs (M^-1)_jj / 2.51 (RK3's real-axis bound): 2.5 rad/s on the index PIP,
    10.7 on its DIP (measured), above Fig 15.25's peak speed.  The physics checked is the bound itself: 10 % below
    that smoothing a small speed grows under RK3; 10 % above it decays."""
    from awiwi_drake.components.friction import stribeck_friction
    jp = FingerRigParams.for_finger("index").joint_friction_params
    from awiwi_drake.hand.plant import make_finger_plant
    plant, _ = make_finger_plant("index")
    M_inv = np.diag(np.linalg.inv(plant.CalcMassMatrix(plant.CreateDefaultContext())))
    bound = np.max(np.abs(np.roots([1 / 6, 1 / 2, 1, 2])))          # |R(z)| = 1 at z = -2.5127 on the real axis
    for joint in (2, 3):
        v_eps = H * jp.static * M_inv[joint] / bound
        for factor, grows in ((0.9, True), (1.1, False)):
            def acc(v):
                return stribeck_friction(v, jp.coulomb, jp.static, jp.stribeck_velocity, factor * v_eps) * M_inv[joint]
            v = 1e-6
            for _ in range(200):
                k1 = acc(v)
                k2 = acc(v + H / 2 * k1)
                k3 = acc(v - H * k1 + 2 * H * k2)
                v += H / 6 * (k1 + 4 * k2 + k3)
            assert (abs(v) > 1e-3) == grows, (joint, factor, v)


@pytest.mark.parametrize("ratio", [0.5, 1.1])
def test_stick_slip_joint_holds_below_the_breakaway_torque_and_slides_above(ratio):
    """The joints' stick-slip law (stick_slip_rate) on the index PIP's inertia (middle + distal about the PIP, the
    finger plant) under a torque raised smoothly from rest (half a cosine over 2 s, so that it does not ring the
    presliding spring, which the law leaves undamped: it has no micro-damping) to ``ratio`` times the breakaway level
    Fs and held for 1 s.  Below the Coulomb level (0.5 Fs < Fc = Fs / 1.5) the joint sticks: it stops (speed far below
    the Stribeck velocity) at a deflection between the closed forms of the presliding law along a monotone path,
    ``-delta (W / Fs) ln(1 - tau / W)``, for the level W at rest (Fs) and at the run's largest speed (``W(v_max)``),
    and the friction holds the torque.  Above Fs it breaks away and slides on, accelerated by at least the torque
    over the breakaway level, ``I qdd >= tau - Fs``."""
    from scipy.integrate import solve_ivp
    from awiwi_drake.components.friction import stick_slip_rate, stribeck_level
    jp = FingerRigParams.for_finger("index").joint_friction_params
    from awiwi_drake.hand.plant import make_finger_plant
    plant, _ = make_finger_plant("index")
    inertia = plant.CalcMassMatrix(plant.CreateDefaultContext())[2, 2]
    tau, ramp, hold = ratio * jp.static, 2.0, 1.0

    def rhs(t, x):
        q, v, f = x
        return [v, (tau * (1.0 - np.cos(np.pi * min(t / ramp, 1.0))) / 2 + f) / inertia,
                stick_slip_rate(f, v, jp.coulomb, jp.static, jp.stribeck_velocity, jp.presliding_angle)]
    sol = solve_ivp(rhs, (0.0, ramp + hold), [0.0, 0.0, 0.0], method="LSODA", rtol=1e-8, atol=1e-11,
                    dense_output=True)
    q, v, f = sol.sol(ramp + hold)
    if ratio * jp.static < jp.coulomb:
        v_max = np.abs(sol.y[1]).max()
        assert v_max < jp.stribeck_velocity and sol.y[1].min() > -0.01 * jp.stribeck_velocity    # monotone path

        def deflection(W):
            return -jp.presliding_angle * (W / jp.static) * np.log(1.0 - tau / W)
        assert deflection(jp.static) <= q <= deflection(stribeck_level(v_max, jp.coulomb, jp.static,
                                                                       jp.stribeck_velocity))
        hold_v = sol.sol(np.linspace(ramp, ramp + hold, 2001))[1]
        assert np.abs(hold_v).max() < 0.01 * jp.stribeck_velocity
        assert f == pytest.approx(-tau, rel=1e-3)
    else:
        assert v > (tau - jp.static) / inertia * hold                 # slides, and keeps accelerating
        assert q > 100 * jp.presliding_angle


def test_finger_energy_balance_with_guide_friction_and_its_passivity_bound():
    """Index finger, motors under constant torques (no motor friction, ripple or hysteresis), guide friction
    and the joints' stick-slip on, links launched: the mechanical energy (links, rotors, springs, minus the constant
    torques' work) falls by exactly the work into the guides int g . (P qdot) dt, into the joints' friction
    -int tau_f . qdot dt and into the joint damping int b qdot^2 dt (energy balance, 1e-3 of the initial kinetic
    energy); the guides' work is at least the change of their Dahl storage delta g^2 / (2 C) (passivity:
    dg/dt = (v/delta)(C - s g) gives g v >= d/dt(delta g^2 / (2 C))), and the joints' at least the change of their
    presliding storage tau_f^2 / (2 sigma0) (stick_slip_rate: -tau_f v >= d/dt(tau_f^2 / (2 sigma0)))."""
    from awiwi_drake.analysis import simulate
    p = FingerRigParams.for_finger("index").with_physics(ripple=False, hysteresis=False, motor_friction=False,
                                                         guide_friction=True, joint_friction=True)
    rig = finger_diagram(finger="index", params=p)
    n, m = rig.num_joints, rig.num_tendons
    op = rig.operating_point()
    ctx = rig.context(op)
    x0 = op.state.copy()
    x0[n:2 * n] = [0.0, 3.0, -2.0, 1.5]                        # [rad/s]: the tendons slide through the guides
    ctx.SetContinuousState(x0)
    res = simulate(rig.diagram, ctx, 0.02, log=("state", "elongation"), mode="error_controlled",
                   accuracy=1e-9, max_step=2e-5, log_period=2e-6)
    X, xs, t = res["state"], res["elongation"], res.t
    q, v = X[:, :n], X[:, n:2 * n]
    theta, omega, g = X[:, 2 * n:2 * n + m], X[:, 2 * n + m:2 * n + 2 * m], X[:, 2 * n + 2 * m:2 * n + 3 * m]
    tau_f = X[:, 2 * n + 3 * m:]
    b = np.array([rig.plant.get_joint(j).default_damping_vector()[0] for j in rig.plant.GetJointIndices()])
    E, slide_power, damp_power = [], [], []
    for k in range(len(t)):
        M = _mass_matrix(rig, q[k])
        P = np.asarray(rig.coupling.P(q[k]))
        springs = sum(float(law.energy(np.array([xs[k, i]]))[0]) for i, law in enumerate(rig.spring_laws))
        E.append(0.5 * v[k] @ M @ v[k] + 0.5 * p.motor.inertia * omega[k] @ omega[k] + springs
                 - op.motor_torque @ theta[k])
        slide_power.append(g[k] @ (P @ v[k]))
        damp_power.append(b @ v[k] ** 2)
    E = np.array(E)
    W_guides = np.concatenate([[0.0], np.cumsum(np.diff(t) * 0.5 * (np.array(slide_power)[1:] + slide_power[:-1]))])
    W_damp = np.concatenate([[0.0], np.cumsum(np.diff(t) * 0.5 * (np.array(damp_power)[1:] + damp_power[:-1]))])
    joint_power = -(tau_f * v).sum(axis=1)
    W_joints = np.concatenate([[0.0], np.cumsum(np.diff(t) * 0.5 * (joint_power[1:] + joint_power[:-1]))])
    ke0 = 0.5 * v[0] @ _mass_matrix(rig, q[0]) @ v[0]
    np.testing.assert_allclose(E + W_guides + W_damp + W_joints, E[0], atol=1e-3 * ke0)
    jp = p.joint_friction_params
    joint_storage = (tau_f ** 2).sum(axis=1) / (2 * jp.static / jp.presliding_angle)
    assert np.all(W_joints >= joint_storage - joint_storage[0] - 1e-3 * ke0)
    assert W_joints[-1] > 0.01 * ke0                            # the joints' friction took its share too
    C = guide_friction_force(tendon_bending_angles(rig.coupling, p), p.friction)
    storage = (p.guide_presliding_length * g ** 2 / (2 * C)).sum(axis=1)
    assert np.all(W_guides >= storage - storage[0] - 1e-3 * ke0)
    assert W_guides[-1] > 0.1 * ke0                             # the guides took a real share of the energy
