"""Diagnose a dataset: find, name, add and confirm missing effects; say what is left.

Loop (issues 6, 12):

1. Replay the logged commands through the model in multiple-shooting windows
   (:class:`~awiwi_drake.discrepancy.replay.ReplayEngine`), profile out the
   window initial states, compare with the noise floor estimated from the data.
2. If the held-out residual energy is at the noise floor: stop ("no effect").
3. Screen every catalog candidate by linear regression of the residual on its
   signature (:mod:`~awiwi_drake.discrepancy.screen`), on training windows,
   scored on held-out windows (blocked split).
4. Fit the best ``num_confirm`` candidates by simulation, the parameters of the
   effects already added free to first order (:mod:`~awiwi_drake.discrepancy.fit`),
   and score them on held-out windows: energy gain, paired statistics over windows,
   BIC on training data, parameters at a bound, materiality
   (:mod:`~awiwi_drake.discrepancy.decide`).
5. Accept the best candidate that passes every test (calibration nuisances win
   ties: the simpler explanation) and refit it jointly with the effects already
   added, by simulation; candidates it cannot be told from form one class "not
   separable" with a suggested experiment.  Repeat.
6. If the held-out residual after the last step is above ``unexplained_ratio``
   times the noise floor, the verdict is "unexplained discrepancy remains", with
   where the residual is (:func:`~awiwi_drake.discrepancy.localise.locate`).
"""

from __future__ import annotations

import math
import time

import numpy as np
from scipy.stats import norm
from threadpoolctl import threadpool_limits

from awiwi_drake.parameters.discrepancy import RIPPLE_MIN_PERIODS, CatalogBounds, DiscrepancySettings

from .catalog import EFFECTS, PARAM_INDEX, PLACED_EFFECTS, default_vector, effects_for_rig
from .data import Dataset, is_finger_rig
from .decide import (EQUIVALENT_EFFECTS, NoiseEquivalent, materiality, recalibration_effect,
                     rejection_reason, ripple_adds_to_recalibration, ripple_periods, separating_experiment)
from .fit import HeldLinear, fit_parameters
from .localise import locate, residual_maps
from .replay import ReplayEngine, project
from .result import CandidateResult, Diagnosis, Step
from .screen import STATEFUL_EFFECTS, ResidualState, free_params, gain_z, nrmse, paired_z, screen

__all__ = ["diagnose", "gap_metrics", "DiagnosisInterrupted", "leftover_rivals"]


class DiagnosisInterrupted(KeyboardInterrupt):
    """Raised when :func:`diagnose` is interrupted (Ctrl-C); ``.diagnosis`` holds the
    partial result (``complete=False``, verdict ``"interrupted"``) up to the last
    accepted step, so callers can still write it."""

    def __init__(self, diagnosis: Diagnosis):
        super().__init__(f"diagnosis of {diagnosis.dataset} interrupted after {len(diagnosis.steps)} step(s)")
        self.diagnosis = diagnosis


class _Run:
    """The state of one diagnosis while it runs (accepted effects, steps, history)."""

    def __init__(self, dataset: Dataset, settings: DiscrepancySettings, bounds: CatalogBounds, say):
        self.t_start, self.cpu_start = time.perf_counter(), time.process_time()
        self.ds, self.settings, self.bounds, self.say = dataset, settings, bounds, say
        self.eng = ReplayEngine(dataset, settings)
        self.rig = dataset.rig
        self.ne = NoiseEquivalent(self.eng)
        self.st0 = self.st = ResidualState(self.eng, default_vector())
        self.nrmse_before = nrmse(self.eng, self.st.rp, self.st.W[self.eng.test])
        self.accepted, self.steps, self.history = [], [], []
        self.recalibration = None   # the drive-gain recalibration when it led a step (not a catalog entry)
        self.stop_reason = ""

    # ---------------------------------------------------------------- one candidate
    def fit_candidate(self, s: dict, held: HeldLinear | None) -> tuple:
        """Simulation fit of one screened candidate's own parameters, the accepted effects' parameters free
        to first order (``held``, :class:`~awiwi_drake.discrepancy.fit.HeldLinear`); the winner is refitted
        jointly with them by simulation in :meth:`accept`. Returns the :class:`CandidateResult` and its
        progress lines."""
        eng, st, rig, eff = self.eng, self.st, self.rig, s["effect"]
        names = [n for n in free_params([eff], rig) if not n.startswith("ripple_order")]
        p_start = st.base.copy()
        for k, v in s["params"].items():
            p_start[PARAM_INDEX[k]] = v
        t0 = time.perf_counter()
        # the current model's window-start profile to start from, unless the effect adds states
        start = None if eff.name in STATEFUL_EFFECTS else st.Q.take(st.W[eng.train])
        fo = fit_parameters(st, names, p_start, self.bounds, self.settings, held, start,
                            resolution=self.settings.fit_resolution)
        rp = project(fo.r0, fo.projection)
        e_after = (rp ** 2).sum(axis=1)
        te, tr = eng.test, eng.train
        gain = float(st.e[te].sum() - e_after[te].sum())
        k = len(eff.amplitude_for(rig)) + len(eff.shape)
        dbic = st.n_train * math.log(max(e_after[tr].sum(), 1e-300) / max(st.e[tr].sum(), 1e-300)) \
            + k * math.log(st.n_train)
        shown = free_params([eff], rig) + (["ripple_order_1", "ripple_order_2"] if eff.name == "motor_ripple" else [])
        params = {n: float(fo.p[PARAM_INDEX[n]]) for n in shown}
        own_bound = [n for n in fo.at_bound if n in shown]
        cr = CandidateResult(eff.name, eff.kind, "fit", params, {n: fo.se.get(n, float("nan")) for n in params},
                             gain, gain / max(st.excess, 1e-12), paired_z(st.e[te], e_after[te]), dbic,
                             own_bound, e_after, gain_z(st.rp[te], rp[te]),
                             materiality(eff.name, params, self.ne), vector=fo.p, profile=(fo.r0, fo.projection))
        cr.rejected = rejection_reason(cr, st, self.settings)
        lines = []
        if cr.at_bound and s.get("fallback"):
            # low ripple orders aliasing each other (a smooth function of the motor angle, large cancelling
            # amplitudes): the pair with the smallest amplitudes the screen cannot tell from the best
            lines.append(f"  fit {eff.name:18s} rests on a bound ({', '.join(cr.at_bound)}): orders "
                         + ", ".join(f"{v:g}" for v in s["fallback"].values()) + " instead")
            alt, alt_lines = self.fit_candidate({**s, "params": dict(s["fallback"]), "fallback": None}, held)
            lines += alt_lines
            if not alt.at_bound:
                return alt, lines
        return cr, lines + [
            f"  fit {eff.name:18s} held-out gain {100 * cr.relative_gain:6.1f}% of excess, "
            f"z {cr.z:4.1f}/{cr.z_gain:6.1f}, dBIC {dbic:9.1f} ({fo.nfev} evals, {fo.rounds} rounds, "
            f"{time.perf_counter() - t0:.1f} s)" + (f": rejected, {cr.rejected}" if cr.rejected else "")]

    # ---------------------------------------------------------------- one step
    def choose(self, fitted: list):
        """The accepted candidate and how sure we are: ``(winner, status, confidence,
        members, alternatives)``, or None when no candidate passes."""
        eng, settings = self.eng, self.settings
        te = eng.test
        passing = sorted([c for c in fitted if not c.rejected], key=lambda c: -c.gain)
        if not passing:
            return None
        win = passing[0]
        nuis = [c for c in passing if c.kind == "nuisance"]
        if win.kind == "physical" and nuis and nuis[0].gain >= settings.ambiguous_ratio * win.gain \
                and paired_z(nuis[0].window_energy[te], win.window_energy[te]) < 1.0:
            win = nuis[0]  # calibration explains as much, within the noise: the simpler explanation
        # candidates that explain as much, not significantly worse: one class
        tied = [c for c in fitted if c is not win and c.gain >= settings.ambiguous_ratio * win.gain
                and paired_z(c.window_energy[te], win.window_energy[te]) < 2.0]
        passing_tied = [c for c in tied if not c.rejected]
        if passing_tied:
            members = sorted([win] + passing_tied, key=lambda c: c.delta_bic)
            win = members[0]  # lowest BIC: fewest parameters for the same fit
        others = [c for c in fitted if c is not win]
        conf = float(norm.cdf(paired_z(others[0].window_energy[te], win.window_energy[te]))) if others else 1.0
        conf = float(min(conf, norm.cdf(win.z - settings.min_rank_z + 2.0)))
        if passing_tied:
            same_kind = [c for c in members if c.kind == win.kind]
            status = "not separable" if len(same_kind) >= 2 else "ambiguous"
            return win, status, conf, [c.effect for c in members], [c.effect for c in members if c is not win]
        # a rejected runner-up that explains as much still makes the choice uncertain
        alts = [c.effect for c in tied]
        return win, ("ambiguous" if alts else "confirmed"), conf, [], alts

    def accept(self, win: CandidateResult, status: str, conf: float, members: list, alts: list, cands: list) -> str:
        """Add ``win`` (refitted jointly with the accepted effects by simulation); returns ``""``, or why it
        is not added: the candidate was judged with the accepted parameters moved to first order, so the
        joint refit must keep a held-out gain that passes the same tests (``min_z`` null standard
        deviations and ``min_floor_gain`` of the noise floor) over the model before the step."""
        first = not self.accepted
        self.accepted.append(EFFECTS[win.effect] if win.effect in EFFECTS else self.recalibration)
        refit = ""
        if first:   # its fit was the joint fit
            self.st = ResidualState(self.eng, win.vector, win.profile)
        else:       # refit jointly with the accepted effects by simulation (its fit moved them to first order)
            names = [n for n in free_params(self.accepted, self.rig) if not n.startswith("ripple_order")]
            t0 = time.perf_counter()
            pol = fit_parameters(self.st, names, win.vector, self.bounds, self.settings,
                                 start_profile=win.profile[1].take(self.st.W[self.eng.train]))
            prev, te = self.st, self.eng.test
            new = ResidualState(self.eng, pol.p, (pol.r0, pol.projection))
            gain, z = prev.E_test - new.E_test, gain_z(prev.rp[te], new.rp[te])
            if gain < self.settings.min_floor_gain * prev.floor_test or z < self.settings.min_z:
                self.accepted.pop()
                return (f"{win.effect} not added: its joint refit by simulation leaves the held-out "
                        f"residual/floor at {new.ratio:.3f} (before the step {prev.ratio:.3f}; gain "
                        f"{z:.1f} null std, {100 * gain / max(prev.floor_test, 1.0):.1f} % of the floor)")
            self.st = new
            refit = (f" (joint refit of {len(names)} parameters: {pol.nfev} evals, {pol.rounds} rounds, "
                     f"{time.perf_counter() - t0:.1f} s)")
        nr = nrmse(self.eng, self.st.rp, self.st.W[self.eng.test])
        experiment = separating_experiment(members) if status == "not separable" else ""
        self.steps.append(Step(win.effect, win.kind, status, conf, win.parameters, win.uncertainties,
                               float(np.mean(list(nr.values()))), nr, alts, cands, members, experiment,
                               place_of(win.effect, self.st.base, self.eng.nom.num_motors)))
        where = self.steps[-1].place
        self.say(f"added {win.effect}{' on ' + where if where else ''} ({win.kind}, {status}, confidence {conf:.2f}); "
                 f"NRMSE {np.mean(list(nr.values())):.4f}, residual/floor {self.st.ratio:.3f}"
                 + (f"; not separable from {', '.join(alts)} with these data: {experiment}" if experiment else "")
                 + refit)
        return ""

    def step(self, all_effects: list) -> bool:
        """One screen-fit-decide round; returns False when the loop stops."""
        settings, st = self.settings, self.st
        if st.ratio < settings.floor_ratio:
            self.stop_reason = f"residual at the noise floor (ratio {st.ratio:.3f} < {settings.floor_ratio})"
            return False
        n_phys = sum(a.kind == "physical" for a in self.accepted)
        n_nuis = len(self.accepted) - n_phys
        pool = [e for e in all_effects if e not in self.accepted
                and ((e.kind == "physical" and n_phys < settings.max_effects)
                     or (e.kind == "nuisance" and n_nuis < settings.max_nuisance))]
        if not pool:
            self.stop_reason = "catalog exhausted (max_effects / max_nuisance reached)"
            return False
        screened = screen(st, pool, self.bounds, self.rig, settings.min_gain)
        self.say("screen: " + ", ".join(f"{s['effect'].name} {100 * s['rel']:.0f}%" for s in screened[:5]))
        screen_results = [CandidateResult(s["effect"].name, s["effect"].kind, "screen", s["params"], {},
                                          s["gain"], s["rel"], s["z"], s["dbic"]) for s in screened]
        best_gain = max([s["gain"] for s in screened] + [0.0])
        # no simulation fit for a candidate whose screened gain is far below what acceptance needs
        least = settings.screen_floor_fraction * settings.min_floor_gain * st.floor_test
        top = [s for s in screened if s["gain"] > settings.confirm_fraction * best_gain
               and s["gain"] >= least][:settings.num_confirm]
        held = None
        if top and self.accepted:   # the accepted parameters' sensitivities, shared by every candidate's fit
            names = [n for n in free_params(self.accepted, self.rig) if not n.startswith("ripple_order")]
            held = HeldLinear(st, names, self.bounds)
        # the candidates' fits side by side, their replays merged (same numbers as one by one)
        fitted = []
        for c, lines in self.eng.run_batched([lambda s=s: self.fit_candidate(s, held) for s in top]):
            for line in lines:
                self.say(line)
            fitted.append(c)
        fitted.sort(key=lambda c: -c.gain)
        self.history.append({"ratio": st.ratio, "screen": [c.summary() for c in screen_results],
                             "fits": [c.summary() for c in fitted]})
        if not top:
            self.stop_reason = (f"no candidate screens a held-out gain of {100 * least / st.floor_test:.2g} % "
                                f"of the noise floor")
            return False
        choice = self.choose(fitted)
        lead = self.ripple_is_calibration(choice[0], fitted, held) if choice and choice[0].effect == "motor_ripple" \
            else None
        if lead is not None:   # the ripple now carries its rejection
            choice = self.choose(fitted)
            if lead and (choice is None or lead.gain >= choice[0].gain):
                # the recalibration leads the class {recalibration, motor_ripple}: a calibration step
                conf = float(norm.cdf(paired_z(fitted[0].window_energy[self.eng.test],
                                               lead.window_energy[self.eng.test])))
                choice = (lead, "not separable", conf, [lead.effect, "motor_ripple"], ["motor_ripple"])
        if choice is None:
            self.stop_reason = "no candidate passes the acceptance tests"
            return False
        win, status, conf, members, alts = choice
        rivals = leftover_rivals(win, status, alts, fitted) if self.accepted else []
        if rivals:
            # a leftover that several effects explain equally (e.g. the form mismatch of an
            # effect already added) names nothing
            self.history[-1]["unresolved"] = [win.effect] + rivals
            self.stop_reason = f"unresolved: {', '.join([win.effect] + rivals)} explain the rest about equally"
            return False
        lost = self.accept(win, status, conf, members, alts, fitted + screen_results)
        if lost:
            self.history[-1]["refit_lost"] = win.effect
            self.stop_reason = lost
            return False
        return True

    def ripple_is_calibration(self, win: CandidateResult, fitted: list, held):
        """A winning ``motor_ripple`` whose largest harmonic completes fewer than ``RIPPLE_MIN_PERIODS`` periods
        over the motor angle covered is a generic smooth function of the angle there; it is not named when it is
        not separable from a calibration, the simpler explanation.  Returns None when the ripple stands; else ``win.rejected`` is
        set and the return is the recalibration's :class:`CandidateResult` when that leads the class (the step
        then adds it, "not separable" from the ripple, with the separating experiment), or ``False`` (the step
        decides among the other candidates):

        * a calibration candidate of this step explains as much held-out residual (the :meth:`choose` tie:
          gain within ``ambiguous_ratio``, not significantly worse window by window), even one that fails a
          test itself: a generic function that absorbs no more of the residual than a rejected calibration is
          no evidence of the physical effect (the benchmark's link spring, seed 9009: 7 % of the excess, a
          force-sensor gain 8 %);
        * or the drive-gain recalibration (:func:`~awiwi_drake.discrepancy.decide.recalibration_effect`) passes
          every test and the ripple's correction adds nothing significant on top of it
          (:func:`~awiwi_drake.discrepancy.decide.ripple_adds_to_recalibration` below ``min_z``): a
          torque-constant error is exactly that recalibration.

        The recalibration is fitted, compared and logged in the step's history; it is a calibration, never a
        physical name."""
        n = self.eng.nom.num_motors
        span = float(min(np.ptp(self.eng.xhat[i]) for i in range(n)))
        periods = ripple_periods(win.parameters, span)
        if periods >= RIPPLE_MIN_PERIODS:
            return None
        te, settings = self.eng.test, self.settings
        generic = (f"its largest harmonic completes {periods:.2f} periods over the {span:.2f} rad of motor angle "
                   f"covered (< {RIPPLE_MIN_PERIODS:g}: a generic function of the angle there)")
        tied = [c for c in fitted if c.kind == "nuisance" and c.gain >= settings.ambiguous_ratio * win.gain
                and paired_z(c.window_energy[te], win.window_energy[te]) < 2.0]
        if tied:
            c = tied[0]
            win.rejected = (f"not separable from the calibration {c.effect}, which explains as much "
                            f"({100 * c.relative_gain:.1f} % of the excess against {100 * win.relative_gain:.1f} %"
                            + (f"; itself rejected: {c.rejected}" if c.rejected else "") + f"): {generic}")
            self.say(f"  {win.effect} rejected: {win.rejected}")
            return False
        bundle = recalibration_effect(self.rig, self.accepted)
        if not bundle.amplitude:
            return None
        rc, lines = self.fit_candidate({"effect": bundle, "params": {}}, held)
        for line in lines:
            self.say(line)
        z = ripple_adds_to_recalibration(self.st.rp, project(*win.profile), project(*rc.profile),
                                         self.eng.train, te)
        self.history[-1]["recalibration"] = {**rc.summary(), "ripple_periods": periods, "ripple_on_top_z": z}
        if rc.rejected or z >= settings.min_z:
            return None
        self.recalibration = bundle
        win.rejected = (f"not separable from a recalibration of the drive gain ({', '.join(bundle.amplitude)}), "
                        f"which explains {100 * rc.relative_gain:.1f} % of the excess and passes every test: "
                        f"{generic}, and its correction adds {z:.1f} null std (< {settings.min_z:g}) on top of the "
                        f"recalibration; to separate them: {separating_experiment(['motor_ripple', 'drive_gain'])}")
        self.say(f"  {win.effect} rejected: {win.rejected}")
        return rc

    def refine_place(self) -> None:
        """The stateful hysteresis (screened by probes on both tendons only), accepted on both tendons as
        the only per-tendon effect in the model, is refitted on each tendon alone (same parameters, place
        masks). With the same number of parameters this is model selection on held-out data: a tendon
        replaces "both tendons" when its variant has the lower held-out residual and the difference is
        significant (held-out gain >= ``min_z`` null standard deviations, as for accepting an effect)."""
        placed = [s for s in self.steps if s.kind == "physical" and s.effect in PLACED_EFFECTS]
        if len(placed) != 1 or placed[0].place != "both tendons" or placed[0].effect not in STATEFUL_EFFECTS:
            return   # the other per-tendon effects had their place variants in the screen
        step, te = placed[0], self.eng.test
        names = [n for n in free_params([EFFECTS[step.effect]], self.rig) if not n.startswith("ripple_order")]
        best, best_st = "both tendons", self.st

        def fit_on(i):
            p0 = self.st.base.copy()
            p0[PARAM_INDEX["place_1"]], p0[PARAM_INDEX["place_2"]] = float(i == 1), float(i == 2)
            return fit_parameters(self.st, names, p0, self.bounds, self.settings)
        for i, fo in zip((1, 2), self.eng.run_batched([lambda i=i: fit_on(i) for i in (1, 2)])):
            st = ResidualState(self.eng, fo.p, (fo.r0, fo.projection))
            if st.E_test < best_st.E_test:
                best, best_st = f"tendon {i}", st
        z = gain_z(self.st.rp[te], best_st.rp[te])
        self.say(f"place of {step.effect}: best {best} (held-out residual/floor {best_st.ratio:.3f} vs "
                 f"{self.st.ratio:.3f} on both tendons, gain {z:.1f} null std)")
        if best != "both tendons" and z >= self.settings.min_z:
            step.place, self.st = best, best_st

    # ---------------------------------------------------------------- result
    def result(self, complete: bool) -> Diagnosis:
        eng, st, settings = self.eng, self.st, self.settings
        named = [s.effect for s in self.steps if s.kind == "physical"]
        nuis = [s.effect for s in self.steps if s.kind == "nuisance"]
        unexplained = bool(st.ratio > settings.unexplained_ratio)
        if not complete:
            verdict = "interrupted"
        elif unexplained:
            verdict = "unexplained discrepancy remains"
        elif named:
            verdict = "effects found" if all(s.status == "confirmed" for s in self.steps) else "ambiguous"
        elif nuis:
            verdict = "calibration only"
        else:
            verdict = "no effect"
        where = {}
        if complete and unexplained:
            where = locate(residual_maps(eng, st.base), settings.unexplained_ratio)
        nr_after = nrmse(eng, st.rp, st.W[eng.test])
        return Diagnosis(
            self.ds.name, self.rig, verdict, named, nuis, list(self.steps),
            float(np.mean(list(self.nrmse_before.values()))), float(np.mean(list(nr_after.values()))),
            self.nrmse_before, nr_after, self.st0.ratio, st.ratio,
            dict(zip(eng.out_names, eng.sigma.tolist())), st.base, time.perf_counter() - self.t_start,
            eng.simulations, time.process_time() - self.cpu_start, eng, list(self.history),
            unexplained, settings.unexplained_ratio, where, self.stop_reason, complete)


def leftover_rivals(win: CandidateResult, status: str, alts: list, fitted: list) -> list:
    """Physical effects that explain a leftover (after other effects were added) as well as the physical
    winner ``win``, so that nothing is named ("unresolved"); [] when ``win`` may be accepted.

    Not rivals: a tied alternative whose fit rests on a bound (a bound is not an estimate, issue 12),
    and the members of a class of :data:`~awiwi_drake.discrepancy.decide.EQUIVALENT_EFFECTS` that all
    pass every test (motor vs guide friction: one class "not separable")."""
    if win.kind != "physical" or status not in ("ambiguous", "not separable"):
        return []
    rivals = [c.effect for c in fitted if c.effect in alts and EFFECTS[c.effect].kind == "physical"
              and not (c.rejected and c.at_bound)]
    if status == "not separable" and all(frozenset((win.effect, a)) in EQUIVALENT_EFFECTS for a in rivals):
        return []
    return rivals


def place_of(effect: str, p: np.ndarray, num_motors: int) -> str:
    """Where a per-tendon effect (:data:`PLACED_EFFECTS`) acts by the place masks of ``p``
    (screened as variants: both tendons, tendon 1 only, tendon 2 only); "" for other effects."""
    if effect not in PLACED_EFFECTS or num_motors != 2:
        return ""
    on = [i + 1 for i in range(2) if p[PARAM_INDEX[f"place_{i + 1}"]] > 0.5]
    return "both tendons" if len(on) == 2 else f"tendon {on[0]}"


def diagnose(dataset: Dataset, *, settings: DiscrepancySettings | None = None,
             bounds: CatalogBounds | None = None, progress=None, checkpoint=None) -> Diagnosis:
    """Run the whole workflow on one dataset (see module docstring).

    Parameters
    ----------
    dataset : Dataset
    settings : DiscrepancySettings, optional
    bounds : CatalogBounds, optional
    progress : callable(str), optional
        Receives one line per stage (the CLI prints them).
    checkpoint : callable(Diagnosis), optional
        Receives the partial result (``complete=False``) after every accepted step
        (the CLI rewrites its JSON, so an interrupted run leaves a partial summary).

    Returns
    -------
    Diagnosis, or for a finger dataset (rig ``finger-*``) a
    :class:`~awiwi_drake.discrepancy.finger.FingerDiagnosis` (effects named with their tendon)

    Raises
    ------
    DiagnosisInterrupted
        On Ctrl-C; its ``diagnosis`` attribute holds the partial result.
    """
    settings = settings or DiscrepancySettings()
    with threadpool_limits(limits=settings.blas_threads, user_api="blas"):
        return _diagnose(dataset, settings, bounds, progress, checkpoint)


def _diagnose(dataset, settings, bounds, progress, checkpoint):
    """:func:`diagnose` under its BLAS thread limit."""
    if is_finger_rig(dataset.rig):   # motor and spring laws per tendon (awiwi_drake.discrepancy.finger)
        from .finger import diagnose_finger
        return diagnose_finger(dataset, settings=settings, bounds=bounds, progress=progress)
    say = progress or (lambda msg: None)
    run = _Run(dataset, settings, bounds or CatalogBounds(), say)
    eng = run.eng
    say(f"{dataset.name}: rig {run.rig}, {len(dataset.time)} samples, {len(eng.starts)} windows of "
        f"{settings.window * 1e3:.0f} ms ({int(eng.train.sum())} train / {int(eng.test.sum())} held out)")
    say("noise floor: " + ", ".join(f"{n} {s:.3g}" for n, s in zip(eng.out_names, eng.sigma)))
    say(f"nominal model: held-out residual / noise floor = {run.st.ratio:.3f}, "
        f"NRMSE {np.mean(list(run.nrmse_before.values())):.4f}")
    all_effects = effects_for_rig(run.rig, eng.out_names)
    try:
        while run.step(all_effects):
            if checkpoint is not None:
                checkpoint(run.result(complete=False))
    except KeyboardInterrupt as exc:
        raise DiagnosisInterrupted(run.result(complete=False)) from exc
    say(run.stop_reason + ": stop")
    try:
        run.refine_place()
    except KeyboardInterrupt as exc:
        raise DiagnosisInterrupted(run.result(complete=False)) from exc
    dx = run.result(complete=True)
    say(f"done in {dx.seconds:.1f} s: {dx.verdict}; named {dx.named_effects or 'nothing'}"
        + "".join(f", {e} on {pl}" for e, pl in dx.places.items())
        + (f", calibration {dx.nuisance_corrections}" if dx.nuisance_corrections else "")
        + (f"; residual/floor {dx.floor_ratio_after:.2f} > {settings.unexplained_ratio:g}: "
           + dx.unexplained.get("text", "") if dx.unexplained_residual else ""))
    return dx


def gap_metrics(dx: Diagnosis, dataset: Dataset) -> dict:
    """Gap closed on held-out windows ``(E_nom - E_aug)/(E_nom - E_truth)`` where
    ``E_truth`` is the projected energy of the actual measurement noise (needs the
    generator's clean outputs in ``dataset.meta['clean_outputs']``)."""
    eng = dx.engine
    clean = dataset.meta.get("clean_outputs")
    if clean is None:
        raise ValueError(f"dataset {dataset.name}: gap_metrics needs the generator's clean outputs")
    W = np.arange(len(eng.starts))
    te = eng.test
    st_nom = ResidualState(eng, default_vector())
    st_aug = ResidualState(eng, dx.final_parameters)
    idx = eng.starts[:, None] + 1 + np.arange(eng.L)[None, :]
    noise = np.stack([(dataset.outputs[o] - clean[o]) for o in eng.out_names], axis=1) / eng.sigma
    nz = noise[idx].reshape(len(W), -1)
    e_truth = float((project(nz, st_aug.Q)[te] ** 2).sum())
    e_nom, e_aug = st_nom.E_test, st_aug.E_test
    closed = (e_nom - e_aug) / max(e_nom - e_truth, 1e-12)
    return {"E_nominal": e_nom, "E_augmented": e_aug, "E_truth": e_truth, "gap_closed": float(closed)}
