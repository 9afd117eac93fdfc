"""Result types of the discrepancy workflow: one scored candidate, one accepted step,
the whole diagnosis (data only; :mod:`~awiwi_drake.discrepancy.report` draws them)."""

from __future__ import annotations

import copy
from dataclasses import dataclass, field, fields

import numpy as np

from .catalog import PARAM_INDEX, PARAM_NAMES, default_vector
from .replay import ReplayEngine

__all__ = ["CandidateResult", "Step", "Diagnosis", "VERDICTS"]

VERDICTS = ("no effect", "effects found", "ambiguous", "calibration only",
            "unexplained discrepancy remains", "interrupted")
"""Possible :attr:`Diagnosis.verdict` values.  ``"unexplained discrepancy remains"``
wins over the others whenever the held-out residual after the last accepted step
is above ``DiscrepancySettings.unexplained_ratio`` times the noise floor (named
effects, if any, are still listed)."""


@dataclass
class CandidateResult:
    """One candidate scored in one step."""

    effect: str
    kind: str
    stage: str  # "screen" or "fit"
    parameters: dict
    uncertainties: dict
    gain: float  # held-out residual energy removed (noise-normalised units)
    relative_gain: float  # gain / held-out energy above the noise floor
    z: float  # Wilcoxon signed-rank z of the per-window held-out improvement
    delta_bic: float  # on training windows (negative: better)
    at_bound: list = field(default_factory=list)
    window_energy: np.ndarray | None = None
    z_gain: float = 0.0  # held-out gain / its null standard deviation (white-noise model)
    materiality: dict = field(default_factory=dict)  # size vs floor (see decide.materiality)
    rejected: str = ""  # why it was not accepted ("" when it passed every test)
    vector: np.ndarray | None = field(default=None, repr=False)  # full fitted parameter vector
    profile: tuple | None = field(default=None, repr=False)  # (residual, window-start profile) at ``vector``

    def summary(self) -> dict:
        return {f.name: copy.deepcopy(getattr(self, f.name)) for f in fields(self)
                if f.name not in ("window_energy", "vector", "profile")}


@dataclass
class Step:
    """One accepted effect (or one class of effects the data cannot separate)."""

    effect: str
    kind: str
    status: str  # "confirmed", "ambiguous" or "not separable"
    confidence: float
    parameters: dict
    uncertainties: dict
    nrmse_after: float
    nrmse_after_signals: dict
    alternatives: list
    candidates: list
    members: list = field(default_factory=list)  # the class when not separable (winner first)
    experiment: str = ""  # an experiment that would separate the members
    place: str = ""  # per-tendon effects: "tendon 1", "tendon 2", "both tendons" or "not localised"

    def summary(self) -> dict:
        return {**{f.name: getattr(self, f.name) for f in fields(self) if f.name != "candidates"},
                "candidates": [c.summary() for c in self.candidates]}


@dataclass
class Diagnosis:
    """Result of :func:`~awiwi_drake.discrepancy.workflow.diagnose` (data; plotting
    and reports take it).

    ``unexplained_residual`` is True when the held-out residual energy after the
    last accepted step is above ``unexplained_ratio`` times the noise floor;
    ``unexplained`` then says where it is (signals, frequency band, operating
    region, cycles per revolution: the summary of the residual maps)."""

    dataset: str
    rig: str
    verdict: str
    named_effects: list
    nuisance_corrections: list
    steps: list
    nrmse_before: float
    nrmse_after: float
    nrmse_before_signals: dict
    nrmse_after_signals: dict
    floor_ratio_before: float
    floor_ratio_after: float
    noise_floor: dict
    final_parameters: np.ndarray
    seconds: float
    simulations: int
    cpu_seconds: float = 0.0
    engine: ReplayEngine = field(repr=False, default=None)
    history: list = field(default_factory=list)
    unexplained_residual: bool = False
    unexplained_ratio: float = float("nan")
    unexplained: dict = field(default_factory=dict)
    stop_reason: str = ""
    complete: bool = True

    @property
    def places(self) -> dict:
        """Where each localised per-tendon effect acts: ``{effect: "tendon 1" | "tendon 2" | ...}``."""
        return {s.effect: s.place for s in self.steps if s.place}

    @property
    def fit_percent_before(self) -> float:
        return 100.0 * (1.0 - self.nrmse_before)

    @property
    def fit_percent_after(self) -> float:
        return 100.0 * (1.0 - self.nrmse_after)

    def to_json(self) -> dict:
        off = default_vector()
        return {
            "dataset": self.dataset, "rig": self.rig, "verdict": self.verdict, "complete": self.complete,
            "named_effects": self.named_effects, "places": self.places,
            "nuisance_corrections": self.nuisance_corrections,
            "unexplained_residual": self.unexplained_residual, "unexplained_ratio": self.unexplained_ratio,
            "unexplained": self.unexplained, "stop_reason": self.stop_reason,
            "nrmse_before": self.nrmse_before, "nrmse_after": self.nrmse_after,
            "fit_percent_before": self.fit_percent_before, "fit_percent_after": self.fit_percent_after,
            "nrmse_before_signals": self.nrmse_before_signals,
            "nrmse_after_signals": self.nrmse_after_signals,
            "floor_ratio_before": self.floor_ratio_before, "floor_ratio_after": self.floor_ratio_after,
            "noise_floor": self.noise_floor,
            "steps": [s.summary() for s in self.steps],
            "final_parameters": {n: float(v) for n, v in zip(PARAM_NAMES, self.final_parameters)
                                 if v != off[PARAM_INDEX[n]]},
            "seconds": self.seconds, "cpu_seconds": self.cpu_seconds, "simulations": self.simulations,
            "history": self.history,
        }
