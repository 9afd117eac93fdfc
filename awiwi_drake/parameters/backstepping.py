"""Parameters of the backstepping controllers (ch. 15) and the optimal gain selection (ch. 16).

Thesis values cite their table/figure/equation; chosen values say why.
Study lists (the gain sets of one figure) are vector fields so that a study is
one parameter set.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from awiwi_drake.parameters.base import Parameters, param

__all__ = [
    "ScalarExampleGains",
    "BacksteppingPlantParams",
    "PositionBacksteppingGains",
    "PositionStudy",
    "ImpedanceBacksteppingGains",
    "ImpedanceStudy",
    "NonlinearImpedanceStudy",
    "PipStudy",
    "AntagonisticBacksteppingGains",
    "OptimalGainsCase",
    "JointRigOptimalGainsCase",
    "FingerOptimalGainsCase",
    "OptimalGainsStudy",
]


@dataclass(frozen=True)
class ScalarExampleGains(Parameters):
    """Gains of the scalar backstepping example (15.1)-(15.10).

    Defaults: the gain set of Fig 15.3 (k1 = k2 = 1); Fig 15.2 uses (0.1, 5), Fig 15.4 (5, 0.1).
    """

    k1: float = param(1.0, unit="1/s", low=0.0, low_inclusive=False, source="Fig 15.3")
    k2: float = param(1.0, unit="1/s", low=0.0, low_inclusive=False, source="Fig 15.3")


@dataclass(frozen=True)
class BacksteppingPlantParams(Parameters):
    """Single flexible joint with a linear spring used in section 15.2/15.3 (Table 15.1).

    ``m qdd = -b_q qd + K (theta - q) + tau_ext``, ``b thdd = -b_theta thd - K (theta - q) + u``.
    """

    link_inertia: float = param(7.2e-7, unit="kg m^2", low=0.0, low_inclusive=False, source="Table 15.1, m")
    motor_inertia: float = param(2e-4, unit="kg m^2", low=0.0, low_inclusive=False, source="Table 15.1, b")
    motor_damping: float = param(1e-2, unit="Nm s/rad", low=0.0, source="Table 15.1, b_theta")
    link_damping: float = param(1e-3, unit="Nm s/rad", low=0.0, source="Table 15.1, b_q")
    stiffness: float = param(20.0, unit="Nm/rad", low=0.0, low_inclusive=False, source="Table 15.1, K")


@dataclass(frozen=True)
class PositionBacksteppingGains(Parameters):
    """Gains k1..k4 of the position controller (15.27), (15.31), (15.37), (15.43).

    Defaults: the set of Fig 15.13 (K1 = 5, K2 = 1) with K3 = K4 = 100 (Table 15.1).
    """

    k1: float = param(5.0, unit="1/s", low=0.0, low_inclusive=False, source="Fig 15.13")
    k2: float = param(1.0, unit="1/s", low=0.0, low_inclusive=False, source="Fig 15.13")
    k3: float = param(100.0, unit="1/s", low=0.0, low_inclusive=False, source="Table 15.1, K3")
    k4: float = param(100.0, unit="1/s", low=0.0, low_inclusive=False, source="Table 15.1, K4")


@dataclass(frozen=True)
class PositionStudy(Parameters):
    """The simulation studies of section 15.2.4 (Fig 15.7, 15.8, 15.10, 15.11, 15.13)."""

    step: float = param(0.8, unit="rad", source="Fig 15.7-15.13: commanded step of 0.8 rad")
    duration: float = param(10.0, unit="s", low=0.0, low_inclusive=False, source="Fig 15.7-15.13 time axes")
    k1_values: tuple = param((0.2, 1.0, 5.0, 50.0), unit="1/s", low=0.0, vector=True, source="Fig 15.7")
    k1_fixed_k2: float = param(1.0, unit="1/s", low=0.0, low_inclusive=False, source="Fig 15.7 (K2 = 1)")
    k2_values: tuple = param((0.2, 1.0, 5.0, 50.0), unit="1/s", low=0.0, vector=True, source="Fig 15.8")
    k2_fixed_k1: float = param(5.0, unit="1/s", low=0.0, low_inclusive=False, source="Fig 15.8 (K1 = 5)")
    saturation: float = param(5e-4, unit="Nm", low=0.0, low_inclusive=False, source="Fig 15.10: |u| < 0.0005")
    saturation_k1: float = param(1.0, unit="1/s", low=0.0, low_inclusive=False, source="Fig 15.10 (K1 = 1)")
    saturation_k2: float = param(1.0, unit="1/s", low=0.0, low_inclusive=False, source="Fig 15.10 (K2 = 1)")
    delays: tuple = param((0.0, 1e-4, 2e-4, 3.33e-4, 5e-4, 1e-3), unit="s", low=0.0, vector=True,
                          source="Fig 15.13 (0, 0.1, 0.2, 0.5, 1 ms) plus the 333 us round trip of section 15.2.4")
    round_trip_delay: float = param(3.33e-4, unit="s", low=0.0,
                                    source="section 15.2.4: 333 us round trip, measure to actuation")
    delay_steps: int = param(8, unit="-", low=1, source="chosen: the controller is sampled at 8/delay (24 kHz for "
                             "333 us) and the command delayed 8 periods; with 2 periods (6 kHz) the exact-cancellation "
                             "loop of the 839 Hz link mode goes unstable (the thesis delays a continuous loop)")
    delay_duration: float = param(4.0, unit="s", low=0.0, low_inclusive=False,
                                  source="chosen: the K1 = 5 response settles within 4 s; sampled runs are costly")


@dataclass(frozen=True)
class ImpedanceBacksteppingGains(Parameters):
    """Gains of the impedance backstepping controller (15.54), (15.57), (15.63).

    Defaults: Kp,imp = 0.1, Kd,imp = 0.05 (middle curves of Fig 15.16); K3 = K4 = 100 (Table 15.1,
    the impedance section prints no K3, K4).
    """

    stiffness: float = param(0.1, unit="Nm/rad", low=0.0, low_inclusive=False, source="Fig 15.16, Kp,imp")
    damping: float = param(0.05, unit="Nm s/rad", low=0.0, low_inclusive=False, source="Fig 15.16, Kd,imp")
    k3: float = param(100.0, unit="1/s", low=0.0, low_inclusive=False,
                      source="chosen: Table 15.1 K3 (section 15.3 prints none)")
    k4: float = param(100.0, unit="1/s", low=0.0, low_inclusive=False,
                      source="chosen: Table 15.1 K4 (section 15.3 prints none)")
    observer_gain: float = param(500.0, unit="1/s", low=0.0, low_inclusive=False,
                                 source="chosen: bandwidth of the external-torque observer (9.2) that supplies the "
                                        "tau_ext (15.62) formally needs; 5x K3")


@dataclass(frozen=True)
class ImpedanceStudy(Parameters):
    """Impedance simulations of section 15.3.3 (Fig 15.16, 15.17)."""

    step: float = param(math.radians(45.0), unit="rad", source="Fig 15.16/15.17: 45 deg step")
    step_time: float = param(0.5, unit="s", low=0.0, source="Fig 15.16/15.17: step at t = 0.5 s")
    disturbance: float = param(0.2, unit="Nm", source="Fig 15.16 caption: 0.2 Nm (the text says 1 Nm)")
    disturbance_time: float = param(1.5, unit="s", low=0.0, source="Fig 15.16/15.17: t = 1.5 s")
    duration: float = param(3.0, unit="s", low=0.0, low_inclusive=False, source="Fig 15.16/15.17 time axis")
    stiffness_values: tuple = param((0.02, 0.1, 0.5), unit="Nm/rad", low=0.0, vector=True, source="Fig 15.16")
    stiffness_fixed_damping: float = param(0.05, unit="Nm s/rad", low=0.0, low_inclusive=False,
                                           source="Fig 15.16 (Kd,imp = 0.05)")
    damping_values: tuple = param((0.01, 0.05, 0.1), unit="Nm s/rad", low=0.0, vector=True, source="Fig 15.17")
    damping_fixed_stiffness: float = param(1.0, unit="Nm/rad", low=0.0, low_inclusive=False,
                                           source="Fig 15.17 (Kp,imp = 1)")


@dataclass(frozen=True)
class NonlinearImpedanceStudy(Parameters):
    """Nonlinear-spring impedance simulations of section 15.4.3 (Fig 15.19-15.21).

    The thesis gives no numbers for this study; the time axis and events follow Fig 15.19
    (step at 0.5 s, load at 1.5 s, 5 s long).
    """

    step: float = param(1.0, unit="rad", source="chosen: Fig 15.19 shows a step of about 1 rad")
    step_time: float = param(0.5, unit="s", low=0.0, source="Fig 15.19/15.20: motion starts at t = 0.5 s")
    disturbance: float = param(0.5, unit="Nm", source="chosen: a load that changes the joint stiffness "
                               "visibly (Fig 15.20), within the spring range")
    disturbance_time: float = param(1.5, unit="s", low=0.0, source="Fig 15.20: load at t = 1.5 s")
    duration: float = param(3.0, unit="s", low=0.0, low_inclusive=False,
                            source="chosen: 3 s shows the settling after the load (Fig 15.19 plots 5 s)")
    stiffness: float = param(1.0, unit="Nm/rad", low=0.0, low_inclusive=False,
                             source="chosen: Kp,imp of Fig 15.17")
    damping: float = param(0.05, unit="Nm s/rad", low=0.0, low_inclusive=False, source="Fig 15.16, Kd,imp")
    k3: float = param(100.0, unit="1/s", low=0.0, low_inclusive=False, source="Table 15.1, K3")
    k4: float = param(100.0, unit="1/s", low=0.0, low_inclusive=False, source="Table 15.1, K4")
    torque_limit: float = param(2.0, unit="Nm", low=0.0, low_inclusive=False,
                                source="chosen: above the 0.5 Nm holding torque, far below the unsaturated "
                                       "command peak (4.9e3 Nm, the kick of the ideal load step)")


@dataclass(frozen=True)
class PipStudy(Parameters):
    """Fig 15.24 / 15.25 (section 15.5.3): the PIP of a finger, backstepping vs cascaded, step and sine
    (:mod:`awiwi_drake.reproductions.ch15_pip_experiments`)."""

    step: float = param(math.radians(30.0), unit="rad", source="Fig 15.24: step to 30 deg (position axis 0-30 deg)")
    step_time: float = param(0.05, unit="s", low=0.0,
                             source="chosen: shortly after the start, so the run begins at rest")
    step_duration: float = param(0.8, unit="s", low=0.0, low_inclusive=False,
                                 source="Fig 15.24 time axis: 0-800 ms")
    step_pretension: float = param(10.0, unit="N", low=0.0, low_inclusive=False,
                                   source="Fig 15.24 caption: f_int = 10 N")
    sine_offset: float = param(math.radians(30.0), unit="rad", source="Fig 15.25: the sine spans 10-50 deg")
    sine_amplitude: float = param(math.radians(20.0), unit="rad", low=0.0,
                                  source="Fig 15.25: the sine spans 10-50 deg")
    sine_frequency: float = param(1.0, unit="Hz", low=0.0, low_inclusive=False,
                                  source="chosen: the thesis prints no frequency for Fig 15.25")
    sine_duration: float = param(2.6, unit="s", low=0.0, low_inclusive=False,
                                 source="Fig 15.25 time axis ends at 2.6 s")
    sine_pretension: float = param(15.0, unit="N", low=0.0, low_inclusive=False,
                                   source="Fig 15.25 caption: f_pre = 15 N")
    guide_friction: bool = param(
        False, unit="-",
        source=("15.5.3: 'a finger with bearings and steel cables' (not the hand's Dyneema tendons in their guides, Fig "
                "4.10): the finger plant without guide friction (with_physics(guide_friction=False)); its joints' "
                "stick-slip (JointFrictionParams) on"))
    plant_substeps: int = param(
        4, unit="-", low=1, high=100,
        source=("chosen: the finger plant integrated at 4 x 3 kHz (fixed-step RK3) under the 3 kHz loop, with the "
                "joints' presliding stiffness scaled by 4^2 (JointFrictionParams.presliding_angle / 16: sigma0 = 4.8 "
                "Nm/rad). RK3's bound on the plant's fastest mode scales with 1/h^2 (docs/REPRODUCTIONS.md, 'Joint "
                "stick-slip friction at 3 kHz'); at the hand's own step a stuck joint is held by at most 0.37 Nm/rad, "
                "softer than the backstepping's designed PIP stiffness (0.46 Nm/rad), so it creeps instead of sticking"))


@dataclass(frozen=True)
class AntagonisticBacksteppingGains(Parameters):
    """Gains of the antagonistic backstepping impedance controller (15.82)-(15.106).

    The desired joint torque is shared equally (15.88) and each tendon keeps the pretension
    ``pretension`` [N] (Fig 15.24: 10 N, Fig 15.25: 15 N, Fig 15.26: 20 N).
    """

    stiffness: float = param(0.5, unit="Nm/rad", low=0.0, low_inclusive=False,
                             source="chosen: inside the range of Fig 15.22 (0.5-5 Nm/rad)")
    damping: float = param(0.01, unit="Nm s/rad", low=0.0, low_inclusive=False,
                           source="chosen: near-critical link damping for 0.5 Nm/rad on the joint rig")
    k3: float = param(100.0, unit="1/s", low=0.0, low_inclusive=False, source="Table 15.1, K3")
    k4: float = param(100.0, unit="1/s", low=0.0, low_inclusive=False, source="Table 15.1, K4")
    pretension: float = param(20.0, unit="N", low=0.0, low_inclusive=False, source="Fig 15.26: f_pre = 20 N")


@dataclass(frozen=True)
class OptimalGainsCase(Parameters):
    """Optimal backstepping gain selection (ch. 16), Table 16.1.

    State of Table 16.1: ``[q, qd, tau, taud]``; ``Q`` and ``R`` weight that state and the motor torque.
    """

    link_inertia: float = param(7.2e-7, unit="kg m^2", low=0.0, low_inclusive=False, source="Table 16.1, M")
    motor_inertia: float = param(2e-3, unit="kg m^2", low=0.0, low_inclusive=False,
                                 source="Table 16.1, Bm = 2e-7 ratio^2, ratio = 100")
    stiffness: float = param(0.605, unit="Nm/rad", low=0.0, low_inclusive=False, source="Table 16.1, K")
    q_weights: tuple = param((100.0, 0.01, 0.01, 0.01), unit="-", low=0.0, vector=True, source="Table 16.1, Q")
    r_weight: float = param(0.1, unit="-", low=0.0, low_inclusive=False, source="Table 16.1, R")
    printed_kdes: tuple = param((-7.7018, -3.8384, -3.8384, -0.0100), unit="mixed", vector=True,
                                source="Table 16.1, Kdes (printed; compared, not used)")
    samples: int = param(20000, unit="-", low=1, source="chosen: Algorithm 3 stabilises after ~1e4 samples here")
    gain_low: tuple = param((1e-3, 1e-4, 1e-1, 1e-1), unit="mixed", low=0.0, low_inclusive=False, vector=True,
                            source="chosen: lower corner of the log-uniform sampling box for "
                                   "(Kp,imp, Kd,imp, K3, K4); Algorithm 3's rand(1,4) scaled")
    gain_high: tuple = param((1e3, 1e2, 1e4, 1e4), unit="mixed", low=0.0, low_inclusive=False, vector=True,
                             source="chosen: upper corner of the sampling box (covers ch. 15's gains)")
    seed: int = param(16, unit="-", low=0, source="chosen: reproducible Monte-Carlo draws")

    def _validate(self) -> None:
        if len(self.q_weights) != 4:
            raise ValueError(f"OptimalGainsCase.q_weights must have 4 entries, got {len(self.q_weights)}")
        for name in ("gain_low", "gain_high"):
            if len(getattr(self, name)) != 4:
                raise ValueError(f"OptimalGainsCase.{name} must have 4 entries (Kp,imp, Kd,imp, K3, K4)")
        for i, (lo, hi) in enumerate(zip(self.gain_low, self.gain_high)):
            if not lo < hi:
                raise ValueError(f"OptimalGainsCase.gain_low[{i}] = {lo} must be below gain_high[{i}] = {hi}")


@dataclass(frozen=True)
class JointRigOptimalGainsCase(OptimalGainsCase):
    """Ch. 16 gain selection on the antagonistic joint rig (N = 2 motors, its own spring law and pretension).

    Table 16.1's weights repeated per tendon (``tau_i``, ``taud_i``), ``R = r I_2``; the link/motor
    inertias and stiffness fields of :class:`OptimalGainsCase` are not used (the rig's own are).
    """

    r_weight: float = param(1e-5, unit="-", low=0.0, low_inclusive=False,
                            source=("chosen: joint rig at 20 N, gain box bounded by the 3 kHz rate "
                                    "(optimal_gains.rate_limited_case): fit distance 4.4 at R = 1e-5 (304 / 46 "
                                    "at 1e-3 / 1e-4; 2.6 at 1e-6 but then a 1 Hz sine saturates 43 %); the 3 kHz "
                                    "loop settles a 0.3 rad step in 53 ms and tracks the sine unsaturated"))


@dataclass(frozen=True)
class FingerOptimalGainsCase(Parameters):
    """Ch. 16 gain selection for each DoF of a finger or the hand
    (:func:`awiwi_drake.control.optimal_gains.select_finger_force_gains`).

    What ch. 16 selects: "the two lower levels of the backstepping controller"; "the two upper gains,
    namely the stiffness and the damping of the impedance controller are directly specified by the
    user" (ch. 16 introduction). So ``Omega = (K3, K4)`` per DoF, while Algorithm 3 draws ``rand(1, 4)``;
    ``Kp,imp``, ``Kd,imp`` are the 15.5 finger law's.
    """

    q_weights: tuple = param((100.0, 0.01, 0.01, 0.01), unit="-", low=0.0, vector=True,
                             source="Table 16.1, Q on [q, qd, tau, taud] (repeated per tendon: tau_i, taud_i)")
    gain_low: float = param(1.0, unit="1/s", low=0.0, low_inclusive=False,
                            source="chosen: lower corner of the (K3, K4) box, a force-error decay of 1 s, far below "
                                   "every joint mode; Algorithm 3's rand(1, 4) has 0 as its lower corner, where "
                                   "(15.63) loses its stability guarantee")
    target_margin: float = param(1.05, unit="-", low=1.0,
                                 source="chosen: the target LQR may be at most 5 % faster than the DoF's fastest "
                                        "open-loop mode where that mode is already beyond the sampled-loop limit "
                                        "(the index DIP: its link on its tendons rings at 1029 rad/s > 750)")
    r_search: tuple = param((1e-12, 1e3), unit="-", low=0.0, low_inclusive=False, vector=True,
                            source="chosen: the bracket of the search for R (Table 16.1's 0.1 inside it)")
    starts: int = param(4, unit="-", low=1, source="chosen: least-squares starts, the best of a few box corners "
                                                   "and draws (the cost is smooth in log Omega)")
    samples: int = param(2000, unit="-", low=1,
                         source="chosen: Algorithm 3 draws used to check the selection (the K_bs of a sample is "
                                "a bilinear form in (K3, K4): 2000 draws cost milliseconds)")
    seed: int = param(16, unit="-", low=0, source="chosen: reproducible draws")

    def _validate(self) -> None:
        if len(self.q_weights) != 4:
            raise ValueError(f"FingerOptimalGainsCase.q_weights must have 4 entries, got {len(self.q_weights)}")
        if len(self.r_search) != 2 or not self.r_search[0] < self.r_search[1]:
            raise ValueError(f"FingerOptimalGainsCase.r_search = {self.r_search} must be (low, high), low < high")


@dataclass(frozen=True)
class OptimalGainsStudy(Parameters):
    """Fig 16.3 / Table 16.2 (section 16.5): independent Algorithm 3 gain selections on the Table 16.2
    model and the link step response of each
    (:func:`awiwi_drake.reproductions.ch16_optimal_backstepping.fig_16_3_gain_samples`)."""

    runs: int = param(10, unit="-", low=1, source="section 16.5 / Fig 16.3: ten distinct experiments")
    samples: int = param(2000, unit="-", low=1,
                         source="chosen: Table 16.2 prints no number of draws; 2000 per run keep the ten runs "
                                "near 15 s (OptimalGainsCase.samples = 20000 is the single-fit default)")
    step: float = param(1.4, unit="rad",
                        source="Fig 16.3: the trajectories level off near 1.4 rad (position axis -0.2 to 1.6 rad); "
                               "the commanded value itself is not printed")
    rise_time: float = param(0.3, unit="s", low=0.0, low_inclusive=False,
                             source="Fig 16.3: the trajectories reach their level in about 0.3 s")
    t_final: float = param(1.2, unit="s", low=0.0, low_inclusive=False, source="Fig 16.3 time axis: 0-1.2 s")
    num: int = param(241, unit="-", low=2, source="chosen: 5 ms output grid over the 1.2 s of Fig 16.3")
    reachable_r_weight: float = param(
        1e-3, unit="-", low=0.0, low_inclusive=False,
        source="chosen: with Table 16.2's R = 0.1 the ARE target lies below the structural floor of "
               "K_bs(Omega) (every fit stops at distance ~5.9, docs/REPRODUCTIONS.md ch. 16); at R = 1e-3 the "
               "ten fits reach distances 0.1-1.0")
    max_step: float = param(1e-3, unit="s", low=0.0, low_inclusive=False,
                            source="chosen: largest integrator step of the continuous loop (<< 0.3 s rise)")
    accuracy: float = param(1e-6, unit="-", low=0.0, low_inclusive=False,
                            source="chosen: error-control accuracy of the step responses")
