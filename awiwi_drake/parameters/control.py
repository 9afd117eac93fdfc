"""Controller parameters (ch. 3, 10-14) with units, ranges and sources."""

from __future__ import annotations

from dataclasses import dataclass

from awiwi_drake.parameters.base import Parameters, param

__all__ = ["TendonForceGains", "ForceSensorParams", "PolePlacementParams", "LqrParams", "SdreTendonParams",
           "SdreJointParams", "ImpedanceParams", "ImpedanceSweepParams", "RippleCompensationParams", "FrictionIdentificationParams",
           "CompareTestParams", "LQR_R_VALUES", "CONTROL_RATE_HZ", "FIXED_STEP_STABILITY_MARGIN",
           "FIXED_STEP_CHECK_INTERVAL"]

#: The hand's control rate [Hz] (ch. 1: 3 kHz, 333 us round trip; the rate of the thesis's experiments).
CONTROL_RATE_HZ = 3000.0

#: Fixed-step stability margin of :func:`~awiwi_drake.analysis.simulate`: when a plant mode lies outside the
#: integrator's stability region at the step ``h``, the plant is integrated at ``h / k`` with the smallest ``k`` that
#: puts every mode, its frequency scaled by this factor, inside (chosen: room for the mode's stiffness to grow by
#: 1.25^2 = 56 % along the run before it leaves the region again; a plant whose modes are inside at ``h`` itself keeps
#: ``k = 1``: at 20 N and 3 kHz the fingers' fastest modes are 3-25 % inside, the hand's 3 %, measured 2026-12-01).
FIXED_STEP_STABILITY_MARGIN = 1.25

#: Simulated time [s] between two re-checks of the plants' modes during a fixed-step run of
#: :func:`~awiwi_drake.analysis.simulate` (at the first progress-chunk boundary after it; chosen: one check of the
#: hand's modes takes 2.4 ms, measured 2026-12-01, and a cascaded hand run takes ~1 s of CPU time per simulated
#: second, so the checks cost it about 1 %; a fixed simulated interval, not a CPU budget, keeps the checked instants
#: and so the reported events the same on every machine).
FIXED_STEP_CHECK_INTERVAL = 0.25

#: Table 13.1: the three input costs of Fig 13.2-13.3.
LQR_R_VALUES = (1e-4, 1e-2, 1.0)


@dataclass(frozen=True)
class TendonForceGains(Parameters):
    """Tendon force PD (10.2) designed by identification (10.10)-(10.11).

    ``Kp = w^2 B / alpha``, ``Kd = 2 xi w B / alpha`` with ``alpha = d f_t / d theta``
    at the design force (fixed gains) or at the reference force (scheduled).
    """

    natural_frequency: float = param(100.0, unit="rad/s", low=0.0, low_inclusive=False,
                                     source="chosen: settles a 5 N step in ~50 ms like Fig 10.3b without "
                                            "saturating the 3 Nm motor",
                                     doc="target w of the motor-position error dynamics (10.10)")
    damping_ratio: float = param(0.7, unit="-", low=0.0, low_inclusive=False,
                                 source="chosen: 4.6 % overshoot makes the damping measurable from a step "
                                        "(Fig 10.3: 'well damped')",
                                 doc="target xi (10.10)")
    design_force: float = param(30.0, unit="N", low=0.0, low_inclusive=False,
                                source="Fig 10.2 (fixed gains tuned for 30 N)",
                                doc="working point of the fixed-gain design")
    min_schedule_force: float = param(2.0, unit="N", low=0.0, low_inclusive=False,
                                      source="chosen: below ~2 N the spring is nearly slack (alpha -> 0); the "
                                             "scheduled gains and the slope alpha of the derivative term "
                                             "(noisy readings near/below 0 N) are held at their 2 N values there")
    friction_compensation: bool = param(True, unit="-", source="(10.2): friction estimate fed forward")
    force_feedforward: bool = param(True, unit="-", source="(10.2): tendon torque r_m f fed forward")
    friction_scale: float = param(1.0, unit="-", low=0.0, high=1.0,
                                  source="chosen: 1 = full model (3.8); < 1 conservative (ch. 3: "
                                         "under- rather than over-compensate)")


@dataclass(frozen=True)
class ForceSensorParams(Parameters):
    """Tendon force sensor: 12-bit Hall sensor with white noise (section 4, 10.4)."""

    bits: int = param(12, unit="bit", low=1, high=24, source="ch. 4: 12-bit Hall sensor at 3 kHz")
    full_scale: float = param(200.0, unit="N", low=0.0, low_inclusive=False,
                              source="chosen: covers the ~180 N top of Fig 4.8b")
    noise_std: float = param(0.1, unit="N", low=0.0,
                             source="chosen: ~2 quantisation steps, noise of Fig 10.4 of a few 0.1 N")
    sample_period: float = param(1.0 / 3000.0, unit="s", low=0.0, low_inclusive=False,
                                 source="ch. 1: 3 kHz control rate")


@dataclass(frozen=True)
class PolePlacementParams(Parameters):
    """Target double oscillator (12.13), Table 12.1."""

    omega1: float = param(100.0, unit="rad/s", low=0.0, low_inclusive=False, source="Table 12.1")
    omega2: float = param(30.0, unit="rad/s", low=0.0, low_inclusive=False, source="Table 12.1")
    xi1: float = param(0.7, unit="-", low=0.0, low_inclusive=False, source="Table 12.1")
    xi2: float = param(0.7, unit="-", low=0.0, low_inclusive=False, source="Table 12.1")
    stiffness_low: float = param(0.43, unit="Nm/rad", low=0.0, low_inclusive=False,
                                 source="Fig 12.3-12.4: K = [0.43, 1.15]")
    stiffness_high: float = param(1.15, unit="Nm/rad", low=0.0, low_inclusive=False,
                                  source="Fig 12.3-12.4: K = [0.43, 1.15]")
    perturbed_stiffness: float = param(0.600, unit="Nm/rad", low=0.0, low_inclusive=False,
                                       source="section 12.3: k 0.605 -> 0.600")
    link_damping_low: float = param(0.0012 * 0.43 / 0.605, unit="Nm s/rad", low=0.0, low_inclusive=False,
                                    source="chosen: Fig 12.3's caption repeats the K range [0.43, 1.15] for D_q "
                                           "(nominal 0.0012, Table 12.1); we use the same relative range "
                                           "x [0.71, 1.90] around 0.0012")
    link_damping_high: float = param(0.0012 * 1.15 / 0.605, unit="Nm s/rad", low=0.0, low_inclusive=False,
                                     source="chosen: see link_damping_low")
    robustness_target_scales: tuple = param((1.0, 3.0, 10.0, 20.0), unit="-", low=0.0, low_inclusive=False,
                                            source="chosen: section 12.3/12.4 says the design is sensitive 'at "
                                                   "least around the selected target dynamics'; (omega1, omega2) "
                                                   "of Table 12.1 times these factors span from the thesis's "
                                                   "targets to beyond the link mode sqrt(k/m) = 1230 rad/s")
    robustness_reference_step: float = param(0.01, unit="rad", low=0.0, low_inclusive=False,
                                   source="chosen: a small joint-angle reference step (the loop is linear, "
                                          "the amplitude only scales the response)")
    robustness_integration_step: float = param(1e-4, unit="s", low=0.0, low_inclusive=False,
                                               source="chosen: fixed RK3 step with |h s| <= 0.07 for every "
                                                      "closed-loop pole of the study (the fastest: (12.19)'s "
                                                      "-622 1/s), local error (h s)^4/24 < 1e-6 per step")
    robustness_window: float = param(0.25, unit="s", low=0.0, low_inclusive=False,
                                     source="chosen: 5 time constants of the slowest target pole "
                                            "(xi2 omega2 = 21 1/s) of Table 12.1")


@dataclass(frozen=True)
class LqrParams(Parameters):
    """LQR of the flexible joint, Table 13.1: state [q, qd, theta, thetad]."""

    q_diag: tuple = param((10.0, 0.01, 1.0, 0.01), unit="mixed", low=0.0, source="(13.9), Table 13.1")
    r: float = param(0.01, unit="1/Nm^2", low=0.0, low_inclusive=False, source="(13.10), Table 13.1")


@dataclass(frozen=True)
class SdreTendonParams(Parameters):
    """SDRE tendon force controller, Table 14.1: state [theta error, theta rate]."""

    q_diag: tuple = param((1.0, 1e-4), unit="mixed", low=0.0, source="Table 14.1")
    r: float = param(1e-6, unit="1/Nm^2", low=0.0, low_inclusive=False, source="Table 14.1")
    update_rate: float = param(200.0, unit="Hz", low=0.0, low_inclusive=False,
                               source="section 14.4: 'a rate of about 200 Hz is sufficient'")
    factorisation: str = param("jacobian", unit="-", choices=("jacobian", "printed"),
                               source=("chosen default: A(x) = tangent of the whole rig (Drake autodiff Jacobian, "
                                       "the (3.8) friction slope included); 'printed' = (14.9) as printed "
                                       "(spring slope only, no friction, no damping; the gains of "
                                       "control.sdre.TendonSdreLaw for one tendon)"))


@dataclass(frozen=True)
class SdreJointParams(Parameters):
    """SDRE nonlinear flexible joint, Table 14.2: state [q, qd, theta, thetad]."""

    q_diag: tuple = param((10.0, 0.01, 0.1, 0.01), unit="mixed", low=0.0, source="Table 14.2")
    r: float = param(1e-4, unit="1/Nm^2", low=0.0, low_inclusive=False, source="Table 14.2")
    link_inertia: float = param(7.2e-7, unit="kg m^2", low=0.0, low_inclusive=False, source="Table 14.2")
    update_rate: float = param(200.0, unit="Hz", low=0.0, low_inclusive=False,
                               source="section 14.4: 'a rate of about 200 Hz is sufficient'")
    factorisation: str = param("jacobian", unit="-", choices=("jacobian", "printed"),
                               source=("chosen default: A(x) = tangent of the whole rig (Drake autodiff Jacobian); "
                                       "'printed' = (14.10) with the secant stiffness k(x1 - x3) = tau_s / (x3 - x1), "
                                       "for which A(x) x reproduces the spring torque exactly"))


@dataclass(frozen=True)
class ImpedanceParams(Parameters):
    """Joint PD, two-time-scale and cascaded impedance (11.3)-(11.4), (11.16)."""

    joint_stiffness: float = param(0.3, unit="Nm/rad", low=0.0, low_inclusive=False,
                                   source="chosen: about half the mechanical stiffness 0.605 (Table 12.1); "
                                          "Fig 11.2 'low impedance stiffness'")
    joint_damping: float = param(5e-4, unit="Nm s/rad", low=0.0,
                                 source="chosen: low damping as in Fig 11.2 (oscillations visible)")
    motor_bandwidth: float = param(150.0, unit="rad/s", low=0.0, low_inclusive=False,
                                   source="chosen: inner motor-position loop of (11.3), Kp = B w^2, faster "
                                          "than the impedance but below the 3 kHz / 333 us delay limit")
    motor_damping_ratio: float = param(0.7, unit="-", low=0.0, low_inclusive=False,
                                       source="chosen: inner loop Kd = 2 xi w B")
    force_bandwidth: float = param(150.0, unit="rad/s", low=0.0, low_inclusive=False,
                                   source="chosen: cascaded force-error dynamics (11.16), same speed as "
                                          "the two-time-scale inner loop for a fair comparison")
    force_damping_ratio: float = param(0.7, unit="-", low=0.0, low_inclusive=False,
                                       source="chosen: cascaded force-error damping (11.16)")
    friction_compensation: bool = param(True, unit="-", source="(11.3): friction estimate b(theta, thetadot)")
    observer_bandwidth: float = param(150.0, unit="rad/s", low=0.0, low_inclusive=False,
                                      source="chosen: momentum observer of the external link torque in the "
                                             "cascaded law (its qdd estimate), as fast as the force loop")


@dataclass(frozen=True)
class ImpedanceSweepParams(Parameters):
    """Fig 11.4: chirp of the link reference, two-time-scale impedance on the antagonistic joint rig."""

    joint_stiffness: float = param(4.0, unit="Nm/rad", low=0.0, low_inclusive=False,
                                   source="chosen: above the mechanical joint stiffness (1.2 / 2.5 Nm/rad at 10 / "
                                          "40 N pretension, from Linearize) so that the time-scale separation of "
                                          "(11.3) fails and resonances show within the 0-70 Hz of Fig 11.4; the "
                                          "thesis prints no gains")
    pretensions: tuple = param((10.0, 20.0, 40.0), unit="N", low=0.0,
                               source="chosen: 'different stiffness' of Fig 11.4 via the pretension (ch. 5: "
                                      "stiffness rises with pretension); 20 N is the rig default")
    f_start: float = param(5.0, unit="Hz", low=0.0, low_inclusive=False, source="Fig 11.4: 0-70 Hz")
    f_stop: float = param(60.0, unit="Hz", low=0.0, low_inclusive=False, source="Fig 11.4: 0-70 Hz")
    duration: float = param(3.0, unit="s", low=0.0, low_inclusive=False,
                            source="chosen: chirp rate 18 Hz/s, slow against the damping of the peaks")
    amplitude: float = param(0.005, unit="rad", low=0.0, low_inclusive=False,
                             source="chosen: small-signal regime: the simulated 10 N peak (38.7 Hz) matches the "
                                    "linearised loop (39.2 Hz); at 0.02 rad it drops to 27 Hz (amplitude-dependent)")


@dataclass(frozen=True)
class RippleCompensationParams(Parameters):
    """Ripple feedforward (section 3.2): known phase, conservative amplitude."""

    amplitude_scale: float = param(0.8, unit="-", low=0.0, high=1.0,
                                   source="chosen: ch. 3 asks for a conservative amplitude estimate "
                                          "(compensate 80 %)")
    speed: float = param(1.0, unit="rad/s", low=0.0, low_inclusive=False,
                         source="Fig 3.5: constant speeds 1 rad/s and 0.5 rad/s")
    duration: float = param(1.0, unit="s", low=0.0, low_inclusive=False,
                            source="chosen: ~16 periods of the motor-shaft ripple at 1 rad/s")
    position_gain: float = param(5.0, unit="Nm/rad", low=0.0, low_inclusive=False,
                                 source="chosen: simple PD of Fig 3.4 (moderate so the ripple shows)")
    velocity_gain: float = param(0.2, unit="Nm s/rad", low=0.0, low_inclusive=False,
                                 source="chosen: simple PD of Fig 3.4")


@dataclass(frozen=True)
class FrictionIdentificationParams(Parameters):
    """Piecewise-constant velocity identification (Fig 3.3)."""

    max_speed: float = param(15.0, unit="rad/s", low=0.0, low_inclusive=False, source="Fig 3.3b: +-15 rad/s")
    min_speed: float = param(0.2, unit="rad/s", low=0.0, low_inclusive=False,
                             source="chosen: resolves the atan knee (gamma1 = 10 s/rad) with >= 1 ripple period per plateau")
    num_speeds: int = param(10, unit="-", low=3, source="chosen: 10 log-spaced plateaus per sign")
    plateau_time: float = param(0.6, unit="s", low=0.0, low_inclusive=False,
                                source="chosen: >= 1 motor-shaft ripple period at the slowest plateau (Fig 3.3a)")
    position_gain: float = param(50.0, unit="Nm/rad", low=0.0, low_inclusive=False,
                                 source="chosen: stiff PD tracking of the ramp (lag < 0.02 rad)")
    velocity_gain: float = param(1.0, unit="Nm s/rad", low=0.0, low_inclusive=False,
                                 source="chosen: PD damping, xi ~ 1.6 with B = 2e-3")
    settle_fraction: float = param(0.3, unit="-", low=0.0, high=0.9,
                                   source="chosen: discard the transient at the start of each plateau")
    torque_noise_std: float = param(0.05, unit="Nm", low=0.0,
                                    source="chosen: pessimistic current-measurement noise, ~10 % of the Coulomb "
                                           "torque 0.56 Nm (Table 3.3) and as large as the ripple (0.054 Nm); "
                                           "averaged over ~1000 samples per plateau")


@dataclass(frozen=True)
class CompareTestParams(Parameters):
    """Standard closed-loop tests of :mod:`awiwi_drake.control.compare` (per rig)."""

    initial_reference: float = param(0.0, unit="ref", finite=True,
                                     source="chosen: link rigs start at their rest angle 0 rad (the tendon rig: "
                                            "10 N, the lowest initial force of Fig 10.2, control.compare.compare_test_params)")
    step_size: float = param(0.3, unit="ref", finite=True,
                             source="chosen: 0.3 rad link step, large enough to show the transient, small enough "
                                    "for the 20 N pretension to keep both tendons taut under impedance control "
                                    "(tendon rig: 5 N steps of Fig 10.2-10.3)")
    step_delay: float = param(0.02, unit="s", low=0.0, source="chosen: short quiet lead-in")
    step_duration: float = param(0.5, unit="s", low=0.0, low_inclusive=False,
                                 source="chosen: the slow pair of Table 12.1 (w2 = 30 rad/s, xi 0.7) settles to 2 % in "
                                        "~4 / (xi w2) = 0.19 s; tendon rig 0.25 s (Fig 10.3 settles in ~50 ms)")
    sine_amplitude: float = param(0.1, unit="ref",
                                  source="chosen: a third of the step, small-signal tracking (tendon rig: 2 N)")
    sine_frequency: float = param(2.0, unit="Hz", low=0.0, low_inclusive=False,
                                  source="chosen: well inside the joint loops' bandwidth (tendon rig: 5 Hz)")
    sine_periods: float = param(3.0, unit="-", low=1.0, source="chosen: first period dropped as transient")
    disturbance_torque: float = param(0.02, unit="Nm", source="chosen: ~0.03 rad deflection at 0.6 Nm/rad")
    load_bound_factor: float = param(0.0, unit="-", low=0.0,
                                     source="chosen: fingers/hand 3 (control.compare.compare_test_params): a loop "
                                            "with the ch. 9 observer compensates up to its friction bound B "
                                            "(components.friction.joint_friction_bound) and the frictions it "
                                            "bounds hold up to another B at rest, so a load L > 2 B is needed "
                                            "before any of it reaches the impedance; at 3 B at least B does, and "
                                            "the measured stiffness L / e lies in [K, 3 K] (K the design's, "
                                            "control.compare.load_stiffness_range). 0: no sizing, every joint "
                                            "gets disturbance_torque (the user's override; the 1-DoF rigs)",
                                     doc="load step = this x the DoF's friction bound (loops with a bounded "
                                         "friction observer)")
    load_linear_fraction: float = param(1.0, unit="-", low=0.0, low_inclusive=False,
                                        source="chosen: the sized load may deflect the joint at its designed "
                                               "stiffness by at most the step test's own step size, the amplitude "
                                               "at which compare already runs the loop as designed; a load that "
                                               "cannot be both is kept at this limit and flagged",
                                        doc="largest load's design deflection L / K, as a fraction of |step_size|")
    max_command_ratio: float = param(2.0, unit="-", low=1.0,
                                     source="chosen: beyond twice the torque limit the motors apply less than "
                                            "half of what the loop commands, so even a short peak is not the "
                                            "designed loop (flagged with its size and duration; the saturated "
                                            "fraction alone misses a 12x peak on 0.5 % of the samples)",
                                     doc="flag a command peak above this x the torque limit")
    sweep_amplitude: float = param(0.05, unit="ref",
                                   source="chosen: small-signal chirp (0.05 rad; tendon rig 1 N) so the gain "
                                          "diagram is the linear one")
    sweep_start: float = param(1.0, unit="Hz", low=0.0, low_inclusive=False, source="Fig 11.4: 0-70 Hz")
    sweep_stop: float = param(70.0, unit="Hz", low=0.0, low_inclusive=False, source="Fig 11.4: 0-70 Hz")
    sweep_duration: float = param(4.0, unit="s", low=0.0, low_inclusive=False,
                                  source="chosen: slow enough chirp for a quasi-steady gain")
    settle_time: float = param(0.3, unit="s", low=0.0, source="chosen: transients of the start decay")
    settling_band: float = param(0.02, unit="-", low=0.0, high=0.5, low_inclusive=False,
                                 source="chosen: 2 % of the step (5 % on the noisy tendon rig)")
    max_saturated_fraction: float = param(0.05, unit="-", low=0.0, high=1.0,
                                          source="chosen: a run whose command is beyond the torque limit for "
                                                 "more than 5 % of the samples is not the designed linear loop "
                                                 "(flagged)")
    max_slack_fraction: float = param(0.0, unit="-", low=0.0, high=1.0,
                                      source="chosen: any slack tendon means an antagonistic joint lost one side "
                                             "of its actuation (flagged)")
    sample_period: float = param(2e-4, unit="s", low=0.0, low_inclusive=False,
                                 source="chosen: logging/hold period for continuous loops")
    max_step: float = param(2e-4, unit="s", low=0.0, low_inclusive=False,
                            source="chosen: RK3 max step, resolves the ~100 Hz modes")


