"""Bounded simulation fit of catalog parameters on the training windows.

The objective is the training residual profiled over the window initial states
(:func:`~awiwi_drake.discrepancy.replay.project`).  The profile depends on the
parameters (an effect with its own state changes the window-start
sensitivities), so the fit alternates: optimise with the profile of the current
point, refresh the profile at the optimum, and repeat until the refreshed cost
agrees with the optimised one (``DiscrepancySettings.fit_rounds``,
``fit_tolerance``).  The candidate is then scored with the same refreshed
profile it was last optimised against, never with one it has not seen.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from awiwi_drake.parameters.discrepancy import CatalogBounds, DiscrepancySettings

from .catalog import PARAM_INDEX, param_specs
from .replay import Projection, project

__all__ = ["FitOutcome", "fit_parameters"]


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


def _one_round(eng, W_train, names, p_start, bounds: CatalogBounds, settings: DiscrepancySettings, Qtr):
    specs = {s.name: s for s in param_specs(bounds)}
    idx = np.array([PARAM_INDEX[n] for n in names])
    lo = np.array([specs[n].low for n in names])
    hi = np.array([specs[n].high for n in names])
    span = hi - lo
    x0 = np.clip(p_start[idx], lo + 1e-6 * span, hi - 1e-6 * span)
    steps = 1e-3 * span
    res_cache, jac_cache = {}, {}

    def vec(x):
        P = p_start[None].copy()
        P[:, idx] = x
        return P

    def fun(x):
        key = x.tobytes()
        if key not in res_cache:
            res_cache.clear()
            res_cache[key] = project(eng.evaluate(vec(x), W_train)[0], Qtr).ravel()
        return res_cache[key]

    def jac(x):
        """Forward differences of all parameters in one batched simulation (d r / d x)."""
        key = x.tobytes()
        if key not in jac_cache:
            r = fun(x)
            h = np.where(x + steps <= hi, steps, -steps)
            P = np.repeat(vec(x), len(x), axis=0)
            for j in range(len(x)):
                P[j, idx[j]] += h[j]
            R = eng.evaluate(P, W_train)
            jac_cache.clear()
            jac_cache[key] = np.stack([(project(R[j], Qtr).ravel() - r) / h[j] for j in range(len(x))], axis=1)
        return jac_cache[key]

    sol = least_squares(fun, x0, jac=jac, bounds=(lo, hi), x_scale=np.maximum(span, 1e-12) * 0.01,
                        max_nfev=settings.max_nfev, ftol=settings.fit_tolerance, xtol=1e-8, method="trf")
    p = p_start.copy()
    p[idx] = sol.x
    r, J = fun(sol.x), jac(sol.x)
    dof = max(r.size - len(names), 1)
    s2 = max(float(r @ r) / dof, 1.0)
    try:
        se = np.sqrt(np.maximum(np.diag(s2 * np.linalg.pinv(J.T @ J)), 0.0))
    except np.linalg.LinAlgError:
        se = np.full(len(names), np.nan)
    # a parameter "at a bound" sits within 0.1 % of the span of a bound that is not its
    # off value (an amplitude resting at zero is simply off) nor a numerical sharpness limit
    at_bound = [n for n, x, l, hgh, sp in zip(names, sol.x, lo, hi, span) if not specs[n].regularisation
                and ((x - l < 1e-3 * sp and l != specs[n].off) or (hgh - x < 1e-3 * sp and hgh != specs[n].off))]
    return p, dict(zip(names, se.tolist())), at_bound, sol.nfev, sol.status > 0, float(r @ r)


def fit_parameters(st, names: list, p_start: np.ndarray, bounds: CatalogBounds,
                   settings: DiscrepancySettings) -> FitOutcome:
    """Fit ``names`` (catalog parameter names) from ``p_start`` on the training windows
    of ``st`` (a :class:`~awiwi_drake.discrepancy.screen.ResidualState`).

    The profile is refreshed on the training windows only while the fit runs; the held-out
    windows' profile (each window is replayed on its own, so this is the same profile) is
    computed once at the result."""
    eng = st.eng
    tr, te = st.W[eng.train], st.W[eng.test]
    _, Qtr = eng.projector(p_start, tr)
    p, nfev_total = p_start, 0
    for rnd in range(1, settings.fit_rounds + 1):
        p, se, at_bound, nfev, converged, cost = _one_round(eng, tr, names, p, bounds, settings, Qtr)
        nfev_total += nfev
        r_tr, Qtr = eng.projector(p, tr)
        refreshed = float((project(r_tr, Qtr) ** 2).sum())
        if abs(refreshed - cost) <= settings.fit_tolerance_refresh * max(cost, 1.0):
            break
    r_te, Qte = eng.projector(p, te)
    pos_tr, pos_te = np.flatnonzero(eng.train), np.flatnonzero(eng.test)
    r0 = np.empty((len(st.W), r_tr.shape[1]))
    r0[pos_tr], r0[pos_te] = r_tr, r_te
    return FitOutcome(p, se, at_bound, nfev_total, converged, rnd, r0,
                      Projection.merge([(pos_tr, Qtr), (pos_te, Qte)]))
