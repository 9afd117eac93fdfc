"""Limits the command line applies to its options before any work starts.

An option outside these limits is a unit mistake or would run without end;
the CLI rejects it with one line naming the option.
"""

from __future__ import annotations

from dataclasses import dataclass

from .base import Parameters, param

__all__ = ["CliLimits", "CompareShortMode"]


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
class CompareShortMode(Parameters):
    """How ``compare --short`` (and ``AWIWI_SHORT=1``) shortens the standard tests.

    The step window comes from the closed loops themselves: ``step_time_constants``
    times the slowest tracking time constant of the compared loops
    (:func:`awiwi_drake.control.compare.dominant_time_constant`), so that a
    well-tuned loop settles; never shorter than ``min_step_duration`` and never
    longer than the full test.
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
