"""Bounded simulation fit of catalog parameters on the training windows.

The objective is the training residual profiled over the window initial states
(:func:`~awiwi_drake.discrepancy.replay.project`).  The profile depends on the
parameters (an effect with its own state changes the window-start
sensitivities), so the fit alternates: optimise with the profile of the current
point, refresh the profile at the optimum, and repeat until the refreshed cost
agrees with the optimised one (``DiscrepancySettings.fit_rounds``,
``fit_tolerance``).  The candidate is then scored with the same refreshed
profile it was last optimised against, never with one it has not seen.

A candidate is fitted with the parameters of the effects already accepted free to
move to first order (:class:`HeldLinear`): their output sensitivities at the
current model are computed once per step, and each candidate's residual is
profiled over them in closed form (variable projection), the way the window
starts are profiled.  Only the candidate's own parameters are simulated, so a
candidate costs the same after three accepted effects as after none; the
accepted candidate is then refitted jointly by simulation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from awiwi_drake.parameters.discrepancy import CatalogBounds, DiscrepancySettings

from .catalog import PARAM_INDEX, param_specs
from .replay import Projection, project

__all__ = ["FitOutcome", "HeldLinear", "fit_parameters"]


@dataclass
class FitOutcome:
    """A finished fit: full parameter vector, standard errors, parameters on a bound,
    function evaluations, whether the optimiser converged, and the profiled residual
    of all windows at the result (``r0``, ``projection``)."""

    p: np.ndarray
    se: dict
    at_bound: list
    nfev: int
    converged: bool
    rounds: int
    r0: np.ndarray
    projection: Projection


class HeldLinear:
    """The accepted effects' parameters ``names`` around the current model ``p`` (catalog vector), to first
    order: forward-difference output sensitivities ``J`` (len(names), W, m) of the unprojected residual on
    all windows (steps of 1e-3 of each span, towards the inside). A fit given a ``HeldLinear`` profiles its
    residual ``r + J delta`` over ``delta`` on the training windows (free, shared by all windows) and
    scores the held-out windows with the training ``delta``."""

    def __init__(self, st, names: list, bounds: CatalogBounds):
        specs = {s.name: s for s in param_specs(bounds)}
        self.names, self.p = list(names), st.base.copy()
        self.idx = np.array([PARAM_INDEX[n] for n in names], dtype=int)
        lo = np.array([specs[n].low for n in names])
        self.lo, self.hi = lo, np.array([specs[n].high for n in names])
        step = 1e-3 * (self.hi - lo)
        x = self.p[self.idx]
        self.h = np.where(x + step <= self.hi, step, -step)
        P = np.repeat(self.p[None], len(names), axis=0)
        P[np.arange(len(names)), self.idx] += self.h
        self.J = (st.eng.evaluate(P, st.W) - st.r0[None]) / self.h[:, None, None]

    def basis(self, windows: np.ndarray, proj) -> np.ndarray:
        """Orthonormal basis (len(windows) * m, k) of the profiled sensitivities on ``windows``."""
        B = project(self.J[:, windows], proj).reshape(len(self.names), -1).T
        q, rr = np.linalg.qr(B)
        keep = np.abs(np.diag(rr)) > 1e-10 * max(float(np.abs(np.diag(rr)).max()), 1e-300)
        return q[:, keep]

    def delta(self, windows: np.ndarray, proj, r: np.ndarray) -> np.ndarray:
        """The parameter change ``delta`` minimising the profiled ``r + J delta`` on ``windows`` (``r``:
        unprojected residual, (len(windows), m))."""
        B = project(self.J[:, windows], proj).reshape(len(self.names), -1).T
        return -np.linalg.lstsq(B, project(r, proj).ravel(), rcond=None)[0]


class _Replays:
    """Unprojected training residuals of one fit, by full parameter vector: the residual at a point
    and the forward-difference residuals of its Jacobian. A profile refresh changes only the
    projection, so the next round reuses the replays of the point it starts from (the few newest
    points are kept)."""

    KEEP = 4

    def __init__(self, eng, windows):
        self.eng, self.windows, self.r, self.J = eng, windows, {}, {}

    @staticmethod
    def _keep(cache: dict, key, value):
        cache[key] = value
        while len(cache) > _Replays.KEEP:
            cache.pop(next(iter(cache)))
        return value

    def residual(self, p: np.ndarray) -> np.ndarray:
        key = p.tobytes()
        hit = self.r.get(key)
        return hit if hit is not None else self._keep(self.r, key, self.eng.evaluate(p[None], self.windows)[0])

    def jacobian(self, p: np.ndarray, idx: np.ndarray, h: np.ndarray) -> np.ndarray:
        """(len(idx), W, m): residuals with parameter ``idx[j]`` stepped by ``h[j]``."""
        key = p.tobytes() + idx.tobytes() + h.tobytes()
        hit = self.J.get(key)
        if hit is not None:
            return hit
        P = np.repeat(p[None], len(idx), axis=0)
        P[np.arange(len(idx)), idx] += h
        return self._keep(self.J, key, self.eng.evaluate(P, self.windows))


class _Resolved(Exception):
    """A trial step of the optimiser whose predicted reduction of the training cost (Gauss-Newton model
    at the last accepted point, in squared noise units) is below the fit's ``resolution``: the fit has
    converged to what the data resolve."""


def _one_round(replays: _Replays, names, p_start, bounds: CatalogBounds, settings: DiscrepancySettings, Qtr,
               held_basis=None, resolution: float = 0.0):
    specs = {s.name: s for s in param_specs(bounds)}
    idx = np.array([PARAM_INDEX[n] for n in names])
    lo = np.array([specs[n].low for n in names])
    hi = np.array([specs[n].high for n in names])
    span = hi - lo
    x0 = np.clip(p_start[idx], lo + 1e-6 * span, hi - 1e-6 * span)
    steps = 1e-3 * span

    def vec(x):
        p = p_start.copy()
        p[idx] = x
        return p

    def profile(R):   # window starts, then the held parameters' linear change (both in closed form)
        R = project(R, Qtr).reshape(R.shape[:-2] + (-1,))
        return R if held_basis is None else R - (R @ held_basis) @ held_basis.T

    last = {}   # the last accepted point and its Jacobian (the optimiser asks for it at every accepted point)
    nfev = [0]

    def fun(x):
        if "J" in last:   # the Gauss-Newton model's cost reduction |r|^2 - |r + J dx|^2 of this trial step
            moved = last["J"] @ (x - last["x"])
            if -float(moved @ (2.0 * last["r"] + moved)) < resolution:
                raise _Resolved   # a step the data cannot resolve: the last accepted point is the optimum
        nfev[0] += 1
        return profile(replays.residual(vec(x)))

    def jac(x):
        """Forward differences of all parameters in one batched simulation (d r / d x)."""
        r = profile(replays.residual(vec(x)))
        h = np.where(x + steps <= hi, steps, -steps)
        R = profile(replays.jacobian(vec(x), idx, h))
        last["x"], last["r"], last["J"] = x.copy(), r, ((R - r) / h[:, None]).T
        return last["J"]

    try:
        sol = least_squares(fun, x0, jac=jac, bounds=(lo, hi), x_scale=np.maximum(span, 1e-12) * 0.01,
                            max_nfev=settings.max_nfev, ftol=settings.fit_tolerance, xtol=1e-8, method="trf")
        x_end, converged = sol.x, sol.status > 0
    except _Resolved:
        x_end, converged = last["x"], True
    last.clear()
    p = p_start.copy()
    p[idx] = x_end
    r, J = fun(x_end), jac(x_end)
    dof = max(r.size - len(names), 1)
    s2 = max(float(r @ r) / dof, 1.0)
    try:
        se = np.sqrt(np.maximum(np.diag(s2 * np.linalg.pinv(J.T @ J)), 0.0))
    except np.linalg.LinAlgError:
        se = np.full(len(names), np.nan)
    # a parameter "at a bound" sits within 0.1 % of the span of a bound that is not its
    # off value (an amplitude resting at zero is simply off) nor a numerical sharpness limit
    at_bound = [n for n, x, l, hgh, sp in zip(names, x_end, lo, hi, span) if not specs[n].regularisation
                and ((x - l < 1e-3 * sp and l != specs[n].off) or (hgh - x < 1e-3 * sp and hgh != specs[n].off))]
    return p, dict(zip(names, se.tolist())), at_bound, nfev[0] - 1, converged, float(r @ r)


def fit_parameters(st, names: list, p_start: np.ndarray, bounds: CatalogBounds,
                   settings: DiscrepancySettings, held: HeldLinear | None = None,
                   start_profile: Projection | None = None, resolution: float = 0.0) -> FitOutcome:
    """Fit ``names`` (catalog parameter names) from ``p_start`` on the training windows
    of ``st`` (a :class:`~awiwi_drake.discrepancy.screen.ResidualState`).

    The profile is refreshed on the training windows only while the fit runs; the held-out
    windows' profile (each window is replayed on its own, so this is the same profile) is
    computed once at the result.

    With ``held`` (:class:`HeldLinear`, parameters not in ``names``), those parameters move to first
    order: the training residual is profiled over their sensitivities, the result's ``p`` carries their
    least-squares change (clipped to the bounds) and its residual ``r0`` is the linearised one
    ``r + J delta`` on all windows.

    ``start_profile`` (the training windows' profile of a nearby point, e.g. the current model's for
    a candidate whose parameters do not change the window-start sensitivities much) saves computing
    it at ``p_start``; the rounds refresh it as usual. A fit whose refreshed training cost is no
    lower than the current model's (``st.E_train``) is not refined further: it explains nothing.

    ``resolution`` (squared noise units; the workflow passes ``DiscrepancySettings.fit_resolution`` for the
    candidates' fits): the optimiser stops at the first trial step whose Gauss-Newton predicted reduction of
    the training cost is below it, instead of shrinking its trust region to ``xtol`` through rejected replays.
    0 runs to the optimiser's own tolerances (the accepted effect's joint refit, on which every later step
    builds)."""
    eng = st.eng
    tr, te = st.W[eng.train], st.W[eng.test]
    Qtr = start_profile if start_profile is not None else eng.projector(p_start, tr)[1]
    p, nfev_total = p_start, 0
    replays = _Replays(eng, tr)
    for rnd in range(1, settings.fit_rounds + 1):
        basis = held.basis(tr, Qtr) if held is not None else None
        p, se, at_bound, nfev, converged, cost = _one_round(replays, names, p, bounds, settings, Qtr, basis,
                                                            resolution)
        nfev_total += nfev
        r_tr, Qtr = eng.projector(p, tr)
        rp_tr = project(r_tr, Qtr).ravel()
        if held is not None:
            basis = held.basis(tr, Qtr)
            rp_tr = rp_tr - basis @ (basis.T @ rp_tr)
        refreshed = float(rp_tr @ rp_tr)
        if abs(refreshed - cost) <= settings.fit_tolerance_refresh * max(cost, 1.0) or refreshed >= st.E_train:
            break
    r_te, Qte = eng.projector(p, te)
    if held is not None:
        delta = held.delta(tr, Qtr, r_tr)
        r_tr = r_tr + np.einsum("k,kwm->wm", delta, held.J[:, tr])
        r_te = r_te + np.einsum("k,kwm->wm", delta, held.J[:, te])
        p = p.copy()
        moved = p[held.idx] + delta
        # a held parameter the first-order step takes past its bound is held at the bound and reported there (the
        # candidate is then judged by the at-bound rule, decide.py), not silently clipped
        at_bound = list(at_bound) + [n for n, x, lo, hi in zip(held.names, moved, held.lo, held.hi)
                                     if (x < lo or x > hi) and n not in at_bound]
        p[held.idx] = np.clip(moved, held.lo, held.hi)
    pos_tr, pos_te = np.flatnonzero(eng.train), np.flatnonzero(eng.test)
    r0 = np.empty((len(st.W), r_tr.shape[1]))
    r0[pos_tr], r0[pos_te] = r_tr, r_te
    return FitOutcome(p, se, at_bound, nfev_total, converged, rnd, r0,
                      Projection.merge([(pos_tr, Qtr), (pos_te, Qte)]))
