"""Parameters of the hand-level algorithms: force distribution (ch. 7), stiffness correction (ch. 8),
joint friction observer (ch. 9).

The thesis prints no numbers for these algorithms beyond Fig 8.3 (1 and 0.7 Nm/rad) and the
epsilon range of (8.2); the remaining values are chosen and say why.
"""

from __future__ import annotations

from dataclasses import dataclass

from awiwi_drake.parameters.base import Parameters, param
from awiwi_drake.parameters.components import JointFrictionParams

__all__ = ["ForceDistributionParams", "StiffnessCorrectionParams", "FrictionObserverParams", "LinkFrictionParams",
           "HandChainParams", "LinkEstimatorParams"]


@dataclass(frozen=True)
class ForceDistributionParams(Parameters):
    """Algorithm 2 (ch. 7): bounds, weights gamma1..3 of (7.7), barrier width, search settings."""

    f_min: float = param(5.0, unit="N", low=0.0,
                         source="chosen: keeps tendons taut with margin (ch. 7: slack must be avoided)")
    f_max: float = param(170.0, unit="N", low=0.0, low_inclusive=False,
                         source="chosen: top of the spring curve of Fig 4.8b (~170-180 N)")
    gamma_stiffness: float = param(1.0, unit="-", low=0.0, source="chosen: gamma1 of (7.7), relative stiffness error")
    gamma_lower: float = param(10.0, unit="-", low=0.0, source="chosen: gamma2 of (7.7), 10x the stiffness term")
    gamma_upper: float = param(10.0, unit="-", low=0.0, source="chosen: gamma3 of (7.7), 10x the stiffness term")
    barrier_width: float = param(2.0, unit="N", low=0.0, low_inclusive=False,
                                 source="chosen: the potentials act within 2 N of a bound")
    iterations: int = param(60, unit="-", low=1, source="chosen: N of Algorithm 2; converged in tests")
    initial_step: float = param(20.0, unit="N", low=0.0, low_inclusive=False,
                                source="chosen: s0 of Algorithm 2, about 1/8 of the force range")
    min_step: float = param(1e-6, unit="N", low=0.0, source="chosen: stop when the halved step is negligible")
    bound_tolerance: float = param(1e-9, unit="N", low=0.0, source="chosen: numerical tolerance of the bounds")

    def _validate(self) -> None:
        if not self.f_min < self.f_max:
            raise ValueError(f"ForceDistributionParams.f_min = {self.f_min} must be below f_max = {self.f_max}")


@dataclass(frozen=True)
class StiffnessCorrectionParams(Parameters):
    """Stiffness correction (ch. 8): K_mech = eps K_eff,des (8.2), K_imp from (8.1)."""

    epsilon: float = param(1.5, unit="-", low=1.0, low_inclusive=False,
                           source="section 8.4: 1.5 shows acceptable results ((8.2): 2-3 also good)")
    min_impedance: float = param(1e-3, unit="Nm/rad", low=0.0, low_inclusive=False,
                                 source="chosen: smallest eigenvalue kept for K_imp (positive definite, section 8.2)")
    max_impedance: float = param(1e3, unit="Nm/rad", low=0.0, low_inclusive=False,
                                 source="chosen: cap of K_imp when K_mech -> K_eff (section 8.3 singular case)")
    targets: tuple = param((1.0, 0.7), unit="Nm/rad", low=0.0, vector=True, source="Fig 8.3: K_eff held at 1 and 0.7")


@dataclass(frozen=True)
class FrictionObserverParams(Parameters):
    """Joint friction observer (9.2)."""

    gain: float = param(100.0, unit="1/s", low=0.0, low_inclusive=False,
                        source="chosen: L of (9.2), observer bandwidth 100 rad/s, above the 1 Hz test motion and "
                               "below the 300 rad/s force loop. In the chain per DoF L / g, g = 1 + K_tau + K_prev the "
                               "stage's torque loop gain (1 for the impedance): its compensation is multiplied by g "
                               "(compensation_scale), which multiplies the observer loop's gain by g. Measured, "
                               "sampled loops at rest: with L = 200 the fifth's LQR stage (g = 2.1-2.7) was unstable "
                               "at ~1110 rad/s (+19.5 1/s with L, +4.8 1/s with L / g and the motor friction and "
                               "ripple off); 100 is stable for all six stages on index, thumb, ring and fifth with the "
                               "physics on, with motor friction and ripple off and with all off. 600 / 1500 rad/s made "
                               "the index's motors chatter (55 / 75 % of a step's 0.5 s saturated, the 'violent "
                               "reaction of motors' of 9.4)")
    compensation_scale: float = param(
        1.0, unit="-", low=0.0, high=1.0, low_inclusive=False,
        source=("(9.1): u = u_c + tau_fric_hat, the whole estimate. At rest the compensation c obeys "
                "c' = L ((G kappa - 1) c + G tau_c), G the static gain from the request to the measured joint torque "
                "(the impedance's tau_c integrates the rest away), so G kappa must stay below 1: a stage with torque "
                "feedback divides what is added to its request by its torque loop gain g = 1 + K_tau + K_prev "
                "(G = 1/g), hence kappa times g per DoF (pole placement, g = 0.5 on the index DIP: +5.1 1/s without "
                "the factor, -0.76 1/s with it; sampled loop at rest)"),
        doc="kappa: fraction of the estimate fed back with the force loop (10.2), per DoF times the stage's torque "
            "loop gain")
    compensation_scale_motor_position: float = param(
        0.9, unit="-", low=0.0, high=1.0, low_inclusive=False,
        source=("chosen: kappa behind the motor-position tendon loop (11.3) (two-time-scale). Measured (sampled "
                "loop at rest, index, L = 200 1/s): kappa = 1 / 0.99 leave the DIP's observer state unstable "
                "(+1.24 / +1.07 1/s), 0.9 is stable (-0.43 1/s); with L = 100 and 0.9: -0.40 1/s"),
        doc="kappa of the two-time-scale chain (motor-position tendon loop)")


@dataclass(frozen=True)
class LinkFrictionParams(Parameters):
    """Link-side stick-slip friction of the observer test joint (ch. 9; values not in the thesis).

    ``tau_f = -(Fc + (Fs - Fc) exp(-(v/vs)^2)) tanh(v/v_eps) - d v``.
    """

    coulomb: float = param(JointFrictionParams.coulomb, unit="Nm", low=0.0,
                           source="chosen: the finger joints' Coulomb level, JointFrictionParams.coulomb (its reason there)")
    static: float = param(JointFrictionParams.static, unit="Nm", low=0.0,
                          source="chosen: the finger joints' breakaway level, JointFrictionParams.static (its reason there)")
    stribeck_velocity: float = param(JointFrictionParams.stribeck_velocity, unit="rad/s", low=0.0, low_inclusive=False,
                                     source="chosen: the finger joints' Stribeck velocity, JointFrictionParams.stribeck_velocity")
    smoothing_velocity: float = param(0.01, unit="rad/s", low=0.0, low_inclusive=False,
                                      source="chosen: tanh regularisation of sign(v); slope Fc/v_eps = 1 Nm s/rad "
                                             "keeps the explicit integrator's steps near 0.1 ms at test_joint_inertia")
    test_joint_inertia: float = param(1e-4, unit="kg m^2", low=0.0, low_inclusive=False,
                                      source="chosen: link + distal chain of a finger on the test fixture; the "
                                             "7.2e-7 of Table 15.1 makes stick-slip too stiff to integrate explicitly")
    viscous: float = param(1e-4, unit="Nm s/rad", low=0.0, source="chosen: small viscous part")


@dataclass(frozen=True)
class HandChainParams(Parameters):
    """The hand's control chain (ch. 7-11): joint impedance -> force distribution -> tendon force PD.

    Per independent DoF the joint law is ``tau = tau_op + K (q_ref - q) - D qdot``, designed from
    the joint's own inertia ``M_jj`` (mass matrix at the operating point): ``D = 2 zeta sqrt(K M_jj)``;
    the cascade limits ``K <= cascade_margin M_jj force_bandwidth^2 / 4`` (the stability bound of (11.16), its joint
    loop behind the force loop).  The mechanical stiffness commanded to the distribution (co-contraction)
    is ``stiffness_scale`` times the operating point's own (5.12) unless given per DoF.  The force
    loop (``tendon_law``) is (10.2) with ``TendonForceGains`` (natural frequency ``force_bandwidth``) or the ch. 14
    tendon SDRE (``sdre_*``), with the friction and ripple feed-forward ``force_friction_scale`` /
    ``force_ripple_scale``.
    """

    force_bandwidth: float = param(300.0, unit="rad/s", low=0.0, low_inclusive=False,
                                   source="chosen: w of the tendon force loop (10.10)-(10.11) on the hand, 1/60 of "
                                          "the 3 kHz rate; 3x the tendon rig's 100 rad/s so that the joint loop "
                                          "behind it can reach a useful stiffness (measured: 100/30 rad/s leaves "
                                          "25 % step error after 0.4 s against motor friction, 300/60 rad/s 0.5 %)")
    joint_stiffness: float = param(0.5, unit="Nm/rad", low=0.0, low_inclusive=False,
                                   source="chosen: Fig 15.22's soft setting, 0.5 Nm/rad (5 Nm/rad the stiff one); "
                                          "that figure is the single flexible-joint testbed with nonlinear springs "
                                          "(section 15.4.4), not a finger: on the finger's PIP the thesis's "
                                          "impedance test (Fig 15.27, section 15.5.3) spans Kp,imp 0-0.1 Nm/rad. "
                                          "An upper bound per DoF here: the cascade caps it at cascade_margin "
                                          "M_jj force_bandwidth^2 / 4, the finger backstepping by its sampled modes",
                                   doc="impedance K per DoF (backstepping: every DoF)")
    cascade_margin: float = param(
        0.5, unit="-", low=0.0, high=1.0, low_inclusive=False,
        source=("chosen: the cascade's stiffness cap is this fraction of the stability bound of (11.16) (section "
                "11.5): the link M q'' + D q' + K q = P^T e_f behind a force loop e_f'' + 2 xi w e_f' + w^2 e_f = 0 "
                "(bandwidth w = force_bandwidth) has the closed loop s^4 + 2 xi w s^3 + w^2 s^2 + w^2 (D s + K) / M, "
                "Hurwitz (Routh) only for K < M (2 xi w d - d^2) / (4 xi^2) with d = D / M, at most M w^2 / 4 "
                "(at D = xi w M) whatever the damping. 0.5 (gain margin 2): cascaded K = min(joint_stiffness, "
                "0.5 M_jj w^2 / 4); on the index PIP (M_jj = 8.8e-6 kg m^2) 0.099 Nm/rad, the top of Fig 15.27's "
                "0-0.1 Nm/rad on the finger's PIP; the DIP (6.2e-7 kg m^2) 0.007 Nm/rad. (The former M_jj (w/5)^2 "
                "was 0.16 of the bound: 0.032 / 0.0022 Nm/rad on the PIP / DIP.)"),
        doc="cascaded K = min(joint_stiffness, cascade_margin M_jj force_bandwidth^2 / 4) per DoF")
    damping_ratio: float = param(0.7, unit="-", low=0.0, low_inclusive=False,
                                 source="chosen: well damped joint response (as (10.10) for the force loop)")
    stiffness_scale: float = param(1.0, unit="-", low=0.0, low_inclusive=False,
                                   source="chosen: 1 holds the operating point's co-contraction (its pretension)")
    distribution_method: str = param("optimal", unit="-", choices=("optimal", "algorithm2"),
                                     source="ch. 7: (7.6) solved by a MathematicalProgram, or Algorithm 2")
    distribution_iterations: int = param(1, unit="-", low=1,
                                         source="chosen: one warm-started QP per control period (the optimum "
                                                "moves little in 1/3000 s; converges over a few periods)")
    scheduled: bool = param(True, unit="-", source="(10.12): force-loop gains scheduled on the reference force")
    sampled_pole_limit: float = param(
        0.25, unit="-", low=0.0, high=1.0, low_inclusive=False,
        source=("chosen: |h lambda| <= 1/4 for the designed joint modes of the finger backstepping at its control "
                "period h (the rule that fixed the joint-rig backstepping at 3 kHz, control/catalog.py); "
                "measured on the index: unclamped the 15.5 joint design has a pole at -6838 1/s (h lambda = -2.3 "
                "at 3 kHz) and the sampled loop's spectral radius is 1.18"))
    friction_scale: float = param(
        0.5, unit="-", low=0.0, high=1.0,
        source=("under-compensation (ch. 3) with a stability margin as backstepping_friction_scale: the sampled loops "
                "at rest (3 kHz, estimator, default physics) of the laws that use it stay stable while the real (3.8) "
                "slope is 14 % below the model's (s <= s_crit / 1.15, the force loop's own margin, "
                "force_friction_scale). The 15.4 (nonlinear-spring) variant is stable up to "
                "s_crit = 0.58 on the index and middle (a 776 Hz link mode, +90 1/s at s = 1), 0.985 on the thumb, "
                "1.14-1.15 on the ring and fifth; the 15.2 (position) variant up to 1.05 (thumb) - 1.16 (index); "
                "two-time-scale is stable at 1 (radius 0.9994 / 0.9998 index / thumb): 0.58 / 1.15 = 0.50. Measured "
                "on a step (0.2 rad on every DoF of the index and the thumb, 3 kHz, estimator, 0.4 s): at 1 none of "
                "the 15.2, 15.4 and two-time-scale loops chatters (no reversal of the motor commands' increments "
                "over the last 0.1 s, rms increment <= 2e-4 Nm per period); the 15.4 index loop's instability at "
                "rest does not show in the step (its guides end at their sliding level, not in presliding). This "
                "source formerly said full compensation 'makes the sampled backstepping chatter': no step shows it"),
        doc="motor friction (3.8) fed forward by the motor-position tendon level (11.3) of "
            "two-time-scale and the 15.2 / 15.4 finger backstepping variants (the (10.2) "
            "force law: force_friction_scale; the 15.5 finger backstepping: "
            "backstepping_friction_scale)")
    backstepping_friction_scale: float = param(
        0.8, unit="-", low=0.0, high=1.0,
        source=("under-compensation (ch. 3: conservative) fixed by two measurements apart from the hand compare that "
                "judges it. (1) Stability margin: at rest only the real (3.8) slope less the fed-forward one enters "
                "the loop, so a plant whose (3.8) is c times the model's sees the fraction s / c. The 15.5 law's "
                "sampled loops at rest (3 kHz, estimator, default physics) are stable up to s_crit = 1.045 on the "
                "thumb and 1.11-1.14 on the index, middle, ring and fifth (with the (9.2) observer, "
                "backstepping-friction-observer: 1.11 / 1.20), so at 0.8 the thumb stays stable while its real slope "
                "is above 77 % of the model's, Table 3.3 being one motor's fit (tests/test_hand_control.py: radius "
                "0.987 at 80 %, 1.001 at 75 %). (2) Motion: 0.9, which gives the fastest decay at rest (thumb / index "
                "radius 0.969 / 0.974 against 0.986 / 0.982 at 0.8), loses the light PIP/DIP mode of the "
                "friction-free index in optimal-backstepping's 4 Hz sine (DIP gain 0.94 -> 0.38, PIP 0.95 -> 1.29; "
                "tests/test_finger_optimal_backstepping.py): the motors' residual friction damps that mode in motion. "
                "No step chatters even at 1 (0.2 rad on every DoF of the index and the thumb, 0.4 s: no reversal of "
                "the command increments over the last 0.1 s; at 1.5 the loop is unstable, rms increment 0.1 Nm per "
                "period). The plain law's rest does not depend on it (the guides' and the lever's friction dead band: "
                "index MCP 0.100 / 0.098 / 0.096 rad short at 0 / 0.5 / 0.95); with the observer its slowest mode at "
                "rest is -0.82 / -1.14 1/s on the thumb at 0.8 / 1. The 15.2 / 15.4 variants keep friction_scale"),
        doc="motor friction (3.8) fed forward by the 15.5 finger backstepping (variant antagonistic)")
    force_friction_scale: float = param(
        1.0, unit="-", low=0.0, high=1.0,
        source=("(10.2): the force law feeds the friction estimate forward, and (10.4): its static force error is "
                "then the model's error over Kp, (tau_fric - tau_fric_hat) / Kp; ch. 3: the compensation 'is "
                "appreciable when the motor is used as a torque source' (tendon force control: 'reduced dead zone'). "
                "The model is (3.8) itself, so 1 (the whole estimate) leaves no static friction error. Not more: "
                "ch. 3 warns against over-compensation (passivity). The sampled force loop stands it: one tendon at "
                "rest, (3.8)'s slope gamma1 gamma2 + gamma3 = 5.6 Nm s/rad held over the 3 kHz period against B / h "
                "= 6 Nm s/rad, has its pair at |z| = 0.955 (s = 1) and loses stability only past s ~ 1.15 "
                "(tests/test_hand_control.py: its continuous loop is the (10.10) design exactly). Measured: at the shared friction_scale 0.5 the residual (3.8) acted "
                "as ~2.8 Nm s/rad below 0.1 rad/s and left the index PIP 0.018 rad from a 0.2 rad step after "
                "0.26 s; at 1: 0.0047 rad"),
        doc="fraction of the motor friction (3.8) the chain's tendon force law (10.2) feeds forward")
    force_ripple_scale: float = param(
        1.0, unit="-", low=0.0, high=1.0,
        source=("(10.2)/(10.4) as force_friction_scale: the ripple (3.5) is a known function of the motor angle (ch. 3: "
                "'the repeatability of the disturbance is excellent and its phase only depends on the motor "
                "position'), so the whole model leaves the force "
                "loop no static ripple error. Not RippleCompensationParams.amplitude_scale (0.8): ch. 3 asks that "
                "'the amplitude estimation must be conservative to avoid introducing potentially destabilizing "
                "energy', as the amplitude of a real motor is not known; here the plant's ripple is (3.5) itself, "
                "so 1 departs from that advice only where the plant departs from the model. A fraction 1 - a "
                "left over is a static force error "
                "(1 - a) tau_r(theta) / Kp_f that moves with the motor angle, i.e. a joint stiffness "
                "sum_i (P S)_ij^2 (1 - a) tau_r'(theta_i) / (r_m Kp_f,i) of either sign (tau_r' up to "
                "N a_m = 5.4 Nm/rad at the motor-shaft period), as large as the distal joints' impedance. Measured, "
                "index, sampled loop at rest (hysteresis off): the slowest mode at -0.11 1/s with a = 0.8, -1.4 1/s "
                "with 1; at half the cascade cap +0.62 1/s (unstable) with 0.8, -0.73 1/s with 1"),
        doc="fraction of the motor ripple (3.5) the chain's tendon force law (10.2) feeds forward")
    tendon_law: str = param(
        "force", unit="-", choices=("force", "sdre"),
        source=("the per-tendon force controller of the chain (ch. 10: 'PD with feed-forward, gain-scheduled', or "
                "SDRE ch. 14): 'force' is (10.2) with the gains (10.11) scheduled per scheduled; 'sdre' the tendon "
                "SDRE (14.7)-(14.9) per tendon (control.sdre.TendonSdreLaw), weights sdre_weights / "
                "sdre_input_weight, re-solved at sdre_update_rate. The designs whose tendon level is their own "
                "(two-time-scale: the motor-position loop (11.3); the 15.5 backstepping: motor torques directly) "
                "refuse 'sdre'"),
        doc="the chain's per-tendon force law: (10.2) 'force' or the ch. 14 SDRE 'sdre'")
    sdre_weights: tuple = param(
        (), unit="(1/rad^2, s^2/rad^2)", low=0.0,
        source=("derived when empty (the default, tendon_sdre_weights): Q = diag(q_theta, q_omega) of the tendon SDRE "
                "on the state [theta - theta_0, omega] (14.9). Its closed loop s^2 + sqrt(c (2 p2 + q_omega)) s + "
                "sqrt(a^2 + c q_theta), c = 1 / (B^2 R), a = r_m alpha / B (control.sdre.tendon_sdre_gains): "
                "q_theta = R (B w_f^2)^2 with w_f = force_bandwidth and B the motor inertia gives "
                "w_n^4 = w_f^4 + a^2, i.e. w_n = 300.0 rad/s at the op's 20 N on the hand (B = 2e-3 kg m^2, Table "
                "14.1's B_theta; a = 165 1/s^2; q_theta = 0.0324 with R = 1e-6), the bandwidth of the (10.2) law it "
                "replaces, which the cascade's stiffness cap and the joint designs assume; q_omega = 0 leaves LQR's "
                "own damping sqrt(2 (w_n^2 - a)) / (2 w_n) = 0.707, the (10.10) design's 0.7. Table 14.1's "
                "Q = diag(1, 1e-4) (the tendon rig, reproductions.ch14_sdre) puts the loop at -100 and -5000 1/s, "
                "3x slower than the force loop the joint designs assume; measured on the index (cascaded, 0.2 rad "
                "MCP step, 3 kHz): it settles too (sampled loop at rest 0.99958 against 0.99949), but its "
                "1000 Nm/rad position gain commands up to 103 Nm against the 3 Nm motors (the derived weights: "
                "9 Nm, as the (10.2) law)"),
        doc="Q = diag(q_theta, q_omega) of the chain's tendon SDRE (tendon_law='sdre'); empty: derived from "
            "force_bandwidth (tendon_sdre_weights)")
    sdre_input_weight: float = param(1e-6, unit="1/(Nm)^2", low=0.0, low_inclusive=False,
                                     source="Table 14.1 (R of the tendon SDRE; only Q / R matters)",
                                     doc="R of the chain's tendon SDRE (tendon_law='sdre')")
    sdre_update_rate: float = param(200.0, unit="Hz", low=0.0, low_inclusive=False,
                                    source="section 14.4: 'a rate of about 200 Hz is sufficient' (the gains "
                                           "re-solved and held between; a continuous chain holds them at the op)",
                                    doc="rate at which the chain's tendon SDRE re-solves its gains")
    link_acceleration_feedforward: bool = param(
        False, unit="-",
        source=("chosen: False. The exact 15.5 design feeds the tendon force change phi' P qdd of its link model's "
                "acceleration forward; on the light finger links that turns any link-side force the model lacks into "
                "motor torque (index DIP: ~8 Nm per N), and with the guides' friction (its presliding stiffness, "
                "absent from the link model) the loop has a pole at +833 1/s (index, continuous, true joint state; "
                "3 kHz through the estimator: spectral radius 1.26). Without it the sampled loop is stable on every "
                "finger and the hand with guide friction (tests/test_hand_control.py); True gives the exact design "
                "(poles equal to the designed error system on the ideal plant)"))

    def _validate(self) -> None:
        super()._validate()
        if self.sdre_weights and (len(self.sdre_weights) != 2 or self.sdre_weights[0] <= 0.0):
            raise ValueError(f"HandChainParams.sdre_weights = {self.sdre_weights!r} must be (q_theta > 0, "
                             f"q_omega >= 0): the tendon SDRE's Q = diag(q_theta, q_omega), or empty (derived)")

    def tendon_sdre_weights(self, motor_inertia: float) -> tuple[float, float]:
        """``(q_theta, q_omega)`` of the chain's tendon SDRE: ``sdre_weights``, or when empty the derived
        ``(R (B force_bandwidth^2)^2, 0)`` (``B = motor_inertia`` [kg m^2]; ``sdre_weights``' source)."""
        if self.sdre_weights:
            return tuple(self.sdre_weights)
        return (self.sdre_input_weight * (motor_inertia * self.force_bandwidth ** 2) ** 2, 0.0)


@dataclass(frozen=True)
class LinkEstimatorParams(Parameters):
    """Joint-state estimation from tendon lengths ((5.15), Algorithm 1) at the control rate."""

    iterations: int = param(15, unit="-", low=1,
                            source="chosen: Algorithm 1 steps per period, warm-started (converged to < 1e-4 rad "
                                   "in tests/test_hand_diagrams.py)")
    initial_step: float = param(0.1, unit="rad", low=0.0, low_inclusive=False,
                                source="chosen: s0 of Algorithm 1")
    rate_hz: float = param(3000.0, unit="Hz", low=0.0, low_inclusive=False,
                           source="thesis: the hand's sensors and control run at 3 kHz (ch. 1); the estimator "
                                  "never runs faster, also under a faster control law")
    gauss_newton_refinement: bool = param(True, unit="-",
                                          source="chosen: one Gauss-Newton step q + (P S)^+ (dh - dh(q)) after "
                                                 "Algorithm 1, which stops on its step size: the least-squares "
                                                 "estimate itself (the velocity below differentiates it)")
    velocity_time_constant: float = param(3.4e-4, unit="s", low=0.0, low_inclusive=False,
                                          source="chosen: about one period (~ the backward difference at 3 kHz); "
                                                 "measured on the thumb, 0.2 rad step: T = 1 ms or 3 ms makes the "
                                                 "6 kHz backstepping saturate in 100 % of the samples, T = 0.34 ms "
                                                 "in 0 %")
