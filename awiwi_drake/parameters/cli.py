"""Settings of the command line: limits on its options, ``compare --short``, and the recording's display.

An option outside :class:`CliLimits` is a unit mistake or would run without end; the CLI rejects it with
one line naming the option.  :class:`AnimationParams` only places the camera of ``awiwi-drake animate``'s
recording (no physics).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .base import Parameters, param
from .hand_control import HandChainParams, StiffnessCorrectionParams

__all__ = ["CliLimits", "CompareShortMode", "AnimationParams", "CompareControllerParams"]


@dataclass(frozen=True)
class CliLimits(Parameters):
    """Upper limits of ``compare --rate/--delay`` and ``animate --duration``."""

    max_rate: float = param(1e5, unit="Hz", low=1.0, high=1e7,
                            source="chosen: 33x the thesis's 3 kHz loops (ch. 10); above, a sampled "
                                   "simulation of the sweep takes hours")
    min_rate: float = param(1.0, unit="Hz", low=0.0, high=1e3,
                            source="chosen: slower than the slowest rig mode (~2 Hz) still runs and is reported "
                                   "as flagged or diverged")
    max_delay: float = param(1.0, unit="s", low=0.0, high=100.0,
                             source="chosen: 3000x the 333 us round trip of the hand (ch. 10); longer than "
                                    "the standard tests")
    max_animation_duration: float = param(60.0, unit="s", low=0.1, high=3600.0,
                                          source="chosen: a minute of the 3 kHz hand loop already takes "
                                                 "minutes of CPU")


@dataclass(frozen=True)
class CompareControllerParams(Parameters):
    """``compare --controller-set NAME=VALUE`` on fingers and the hand: the controllers' ``chain``
    (:class:`HandChainParams`, e.g. ``distribution_method=algorithm2``) and the ch. 8 stiffness correction of the
    chain designs (``stiffness_correction=true``, its ``epsilon`` ... in ``correction``)."""

    chain: HandChainParams = field(default_factory=HandChainParams)
    stiffness_correction: bool = param(False, unit="-", source="chosen: off, as the registered chain controllers "
                                                               "(ch. 8's correction is an option of the chain)")
    correction: StiffnessCorrectionParams = field(default_factory=StiffnessCorrectionParams)

    def factory_options(self) -> dict:
        """The controller factories' options these set (:func:`~awiwi_drake.control.registry.make_controller`);
        the defaults set none."""
        opts = {} if self.chain == HandChainParams() else {"chain_params": self.chain}
        return {**opts, "stiffness_correction": self.correction} if self.stiffness_correction else opts


@dataclass(frozen=True)
class CompareShortMode(Parameters):
    """How ``compare --short`` (and ``AWIWI_SHORT=1``) shortens the standard tests.

    The step window is ``step_time_constants`` times the slowest tracking time constant of the compared
    loops (:func:`awiwi_drake.control.compare.dominant_time_constant`), at least ``min_step_duration``.
    """

    step_time_constants: float = param(5.0, unit="-", low=1.0, high=20.0,
                                       source="chosen: a first-order mode is within 0.7 % after 5 time constants "
                                              "(inside the 2 % settling band)")
    min_step_duration: float = param(0.15, unit="s", low=0.01, high=10.0,
                                     source="chosen: the earlier fixed short window, kept as a floor")
    sweep_duration: float = param(1.0, unit="s", low=0.1, high=100.0,
                                  source="chosen: 1 Hz frequency resolution of the chirp's gain diagram")
    settle_time: float = param(0.1, unit="s", low=0.0, high=10.0,
                               source="chosen: start transients of the sampled loops decay within 0.1 s")
    sine_periods: float = param(2.0, unit="-", low=2.0, high=100.0,
                                source="chosen: the first period is dropped as transient, one is measured")


@dataclass(frozen=True)
class AnimationParams(Parameters):
    """Camera, forearm stub and frame rate of a hand/finger recording.

    The recording shows the palm frame turned so that the fingers point up and the palm faces the display
    x axis; the camera looks at the centre of the moving links' box from ``camera_azimuth`` /
    ``camera_elevation``, far enough that the box fills ``fill_fraction`` of the vertical field of view.
    """

    frame_rate: float = param(30.0, unit="Hz", low=1.0, high=240.0,
                              source="chosen: smooth playback, small HTML file")
    camera_azimuth: float = param(-0.75, unit="rad", low=-3.1416, high=3.1416,
                                  source="chosen: three-quarter view from the palm and thumb side, "
                                         "so that flexion is seen in profile")
    camera_elevation: float = param(0.35, unit="rad", low=-1.5, high=1.5,
                                    source="chosen: slightly from above, fingertips not hidden by the palm")
    field_of_view: float = param(75.0, unit="deg", low=10.0, high=120.0,
                                 source="chosen: Meshcat's default perspective camera (three.js fov 75 deg)")
    fill_fraction: float = param(0.95, unit="-", low=0.2, high=1.5,
                                 source="chosen: the bounding sphere of the moving links fills 95 % of the view height")
    margin: float = param(0.015, unit="m", low=0.0, high=0.1,
                          source="chosen: about two link radii around the link origins")
    forearm_length: float = param(0.08, unit="m", low=0.0, high=0.5,
                                  source="chosen: a short stub that shows where the wrist is")
    forearm_radius: float = param(0.028, unit="m", low=0.005, high=0.1,
                                  source="chosen: about a human wrist (56 mm across)")
    show_grid: bool = param(False, unit="-", source="chosen: the ground grid cuts through the upright hand")
