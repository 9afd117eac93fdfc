"""Screening: linear regression of the residual on each candidate's signature.

:class:`ResidualState` holds the base residual of the current model (profiled
over the window initial states, see :mod:`~awiwi_drake.discrepancy.replay`);
:func:`screen` regresses it on the finite-difference output sensitivities of
every candidate's amplitude parameters (shape parameters on a small grid, ripple
orders from the residual's cycles-per-revolution spectrum), fitting on training
windows and scoring on held-out windows; :func:`probe` evaluates effects whose
signature changes with amplitude at finite amplitudes.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import rankdata

from awiwi_drake.parameters.discrepancy import CatalogBounds

from .catalog import EFFECTS, PARAM_INDEX, PLACED_EFFECTS, Effect, param_specs
from .localise import cpr_spectrum
from .replay import ReplayEngine, project

__all__ = ["ResidualState", "nrmse", "paired_z", "gain_z", "screen", "probe", "free_params",
           "STATEFUL_EFFECTS"]


class ResidualState:
    """Base residual of the current model ``base`` (catalog vector): profiled residual
    ``rp`` per window, window energies ``e``, held-out energy ``E_test`` against its
    noise floor ``floor_test`` (degrees of freedom left by the profile), ``ratio``."""

    def __init__(self, eng: ReplayEngine, base: np.ndarray, profile: tuple | None = None):
        self.eng = eng
        self.base = base.copy()
        self.W = np.arange(len(eng.starts))
        # ``profile``: the residual and window-start profile of ``base`` on all windows when already
        # computed (a fit's result, :class:`~awiwi_drake.discrepancy.fit.FitOutcome`)
        r0, Q = profile if profile is not None else eng.projector(base, self.W)
        self.Q = Q
        self.r0 = r0
        self.rp = project(r0, Q)
        self.e = (self.rp ** 2).sum(axis=1)
        self.dof = Q.dof
        te, tr = eng.test, eng.train
        self.E_test = float(self.e[te].sum())
        self.E_train = float(self.e[tr].sum())
        self.floor_test = float(self.dof[te].sum())
        self.excess = max(self.E_test - self.floor_test, 0.0)
        self.ratio = self.E_test / max(self.floor_test, 1.0)
        self.n_train = int(r0[tr].size)


def nrmse(eng: ReplayEngine, rp: np.ndarray, windows: np.ndarray) -> dict:
    ny = len(eng.out_names)
    R = rp[windows].reshape(len(windows), eng.L, ny) * eng.sigma
    return {name: float(np.sqrt(np.mean(R[:, :, j] ** 2)) / eng.spread[j])
            for j, name in enumerate(eng.out_names)}


def paired_z(e_before: np.ndarray, e_after: np.ndarray) -> float:
    """Wilcoxon signed-rank z of the per-window improvement ``e_before - e_after``.

    Robust to the heavy tails of window energies (a few transient-rich windows
    carry most of the energy); positive when most windows improve."""
    d = np.asarray(e_before, float) - np.asarray(e_after, float)
    d = d[d != 0]
    n = len(d)
    if n < 2:
        return 0.0
    ranks = rankdata(np.abs(d))
    w_plus = ranks[d > 0].sum()
    mean = n * (n + 1) / 4.0
    sd = math.sqrt(n * (n + 1) * (2 * n + 1) / 24.0)
    return float((w_plus - mean) / sd)


def gain_z(rp_before: np.ndarray, rp_after: np.ndarray) -> float:
    """Held-out gain over its null spread: with white residual ``r`` and a prediction
    change ``delta`` unrelated to it, the gain ``|r|^2 - |r - delta|^2`` has mean
    ``-|delta|^2`` and standard deviation ``2 |delta|``."""
    delta = rp_before - rp_after
    nd = math.sqrt(float((delta ** 2).sum()))
    gain = float((rp_before ** 2).sum() - (rp_after ** 2).sum())
    return gain / (2.0 * nd) if nd > 0 else 0.0


def ripple_orders_from_spectrum(st: "ResidualState", bounds: CatalogBounds) -> list:
    """Ripple orders to screen: the expected ``bounds.ripple_orders`` plus
    ``bounds.ripple_candidates`` other lines (orders 1..``ripple_order_max``) of the current
    residual's cycles-per-revolution spectrum (summed over the signals, against every
    motor angle): half the strongest, half the most prominent over their neighbours."""
    eng = st.eng
    ny = len(eng.out_names)
    idx = (eng.starts[st.W][:, None] + 1 + np.arange(eng.L)[None, :]).ravel()
    R = st.rp.reshape(len(st.W), eng.L, ny).reshape(-1, ny)
    orders = np.arange(1, int(bounds.ripple_order_max) + 1)
    amps = cpr_spectrum(R, [eng.xhat[i][idx] for i in range(eng.nom.num_motors)], orders)
    power = (amps ** 2).sum(axis=1)
    # half by power, half by prominence over the neighbouring orders (+-10): a coloured residual
    # fills the low orders with power, a weak gear line at 100/rev stands out only locally
    local = np.array([np.median(power[max(0, i - 10):i + 11]) for i in range(len(power))])
    prominence = power / np.maximum(local, 1e-300)
    expected = [float(o) for o in bounds.ripple_orders if o <= bounds.ripple_order_max]
    fresh = [i for i in range(len(orders)) if float(orders[i]) not in expected]
    k = bounds.ripple_candidates
    picked = sorted(fresh, key=lambda i: -power[i])[:(k + 1) // 2]
    picked += [i for i in sorted(fresh, key=lambda i: -prominence[i]) if i not in picked][:k - len(picked)]
    return expected + [float(orders[i]) for i in picked]


def ripple_pair(entries: list, b: np.ndarray, tie: float) -> list:
    """The ripple orders a fit falls back to when the screened pair's fit rests on the amplitude bound:
    of the pairs whose joint least-squares gain on the training residual ``b`` is within ``tie`` of the
    best pair's, the one with the smallest largest amplitude.

    Over an angle range shorter than a period, low orders alias each other: many pairs fit the same
    smooth function of the motor angle, some with large cancelling amplitudes that the simulation fit
    drives onto the amplitude bound (a rejected fit, and the step names nothing). The true pair fits
    with the true amplitudes, an aliasing pair needs larger ones, so the smallest amplitudes among the
    pairs the data cannot tell apart is the choice (``tie``: the workflow passes ``min_gain`` of the
    training excess, the least gain it accepts as an effect)."""
    if len(entries) < 2:
        return list(entries)
    A = np.concatenate([e["g"] for e in entries], axis=-1)
    A = A.reshape(-1, A.shape[-1])
    G, Ab = A.T @ A, A.T @ b     # normal equations of every pair from one Gram matrix
    k = entries[0]["g"].shape[-1]
    fits = []
    for i in range(len(entries)):
        for j in range(i + 1, len(entries)):
            cols = np.r_[i * k:(i + 1) * k, j * k:(j + 1) * k]
            coef = np.linalg.lstsq(G[np.ix_(cols, cols)], Ab[cols], rcond=None)[0]
            fits.append((float(coef @ Ab[cols]), float(np.abs(coef).max()), [entries[i], entries[j]]))
    best = max(f[0] for f in fits)
    pair = min((f for f in fits if f[0] >= best - tie), key=lambda f: f[1])[2]
    return sorted(pair, key=lambda e: -e["train_gain"])


def candidate_grid(effect: Effect, rig: str, base: np.ndarray, bounds: CatalogBounds, ripple_orders=()):
    """Screening variants ``(label, shape_values, [(param, delta)...], ripple_order)``
    (``ripple_orders``: the orders screened for ``motor_ripple``)."""
    specs = {s.name: s for s in param_specs(bounds)}
    amps = effect.amplitude_for(rig)
    if effect.name == "motor_ripple":
        out = []
        for order in ripple_orders:
            cols = [a for a in amps if a.startswith(("ripple_sin1", "ripple_cos1"))]
            out.append((f"order {order:g}", {"ripple_order_1": order},
                        [(c, specs[c].perturbation) for c in cols], order))
        return out
    cols = [(a, specs[a].perturbation) for a in amps]
    if not effect.shape:
        out = [("", {}, cols, None)]
    else:
        (sname, grid), = effect.shape.items()
        out = [(f"{sname}={g:g}", {sname: g}, cols, None) for g in grid]
    # a per-tendon effect is screened on both tendons and on each alone (its place), unless a
    # per-tendon effect is already in the model (the place masks are shared)
    placed = [n for e in PLACED_EFFECTS for n in EFFECTS[e].amplitude_for(rig)]
    if (effect.name in PLACED_EFFECTS and rig == "joint-rig" and not np.any(base[[PARAM_INDEX[n] for n in placed]])
            and base[PARAM_INDEX["place_1"]] == 1.0 and base[PARAM_INDEX["place_2"]] == 1.0):
        out += [(f"{label} tendon {i}".strip(), {**shape, "place_1": float(i == 1), "place_2": float(i == 2)},
                 c, o) for i in (1, 2) for label, shape, c, o in list(out)]
    return out


def screen(st: ResidualState, effects: list, bounds: CatalogBounds, rig: str, min_gain: float = 0.0) -> list:
    """Linear-regression screening of every candidate; returns dicts sorted by held-out gain
    (``min_gain``: the fraction of the excess an accepted effect must remove, the tie of
    :func:`ripple_pair`)."""
    eng, base = st.eng, st.base
    variants = []  # (effect, label, shape, cols, order)
    Psets = []
    orders = ripple_orders_from_spectrum(st, bounds) if any(e.name == "motor_ripple" for e in effects) else []
    for eff in effects:
        for label, shape, cols, order in candidate_grid(eff, rig, base, bounds, orders):
            p0 = base.copy()
            for k, v in shape.items():
                p0[PARAM_INDEX[k]] = v
            idx = []
            for name, delta in cols:
                p = p0.copy()
                p[PARAM_INDEX[name]] += delta
                idx.append(len(Psets))
                Psets.append(p)
            shape_idx = None
            if shape and order is None:
                shape_idx = len(Psets)
                Psets.append(p0)  # shape change alone (Dahl state init etc.): reference
            variants.append((eff, label, shape, cols, order, idx, shape_idx))
    # every variant is replayed on the training windows, where the choices are made; only the chosen
    # variants are replayed on the held-out windows that score them
    tr, te = eng.train, eng.test
    Q_tr, Q_te = st.Q.take(st.W[tr]), st.Q.take(st.W[te])
    R_tr = eng.evaluate(np.array(Psets), st.W[tr])

    def signature(R, r0, Q, idx, shape_idx, cols):
        """Profiled sensitivities (W, m, k) and profiled reference residual of one variant."""
        ref = r0 if shape_idx is None else R[shape_idx]
        g = np.stack([(ref - R[i]) / d for i, (_, d) in zip(idx, cols)], axis=0)
        return np.moveaxis(project(g, Q), 0, -1), project(ref, Q)

    results = {}
    rp_tr = st.rp[tr]
    for eff, label, shape, cols, order, idx, shape_idx in variants:
        g, rp = signature(R_tr, st.r0[tr], Q_tr, idx, shape_idx, cols)
        A = g.reshape(-1, g.shape[-1])
        b = rp.ravel()
        beta, *_ = np.linalg.lstsq(A, b, rcond=None)
        res_tr = b - A @ beta
        train_gain = float((rp_tr ** 2).sum() - (res_tr ** 2).sum())
        entry = dict(effect=eff, label=label, shape=shape, cols=cols, order=order, beta=beta,
                     train_gain=train_gain, g=g, rp=rp, sets=(idx, shape_idx))
        results.setdefault(eff.name, []).append(entry)
    chosen = []   # (effect, [entries], label, shape, cols)
    fallback = {}  # effect: parameters a fit resting on a bound starts again from
    for name, entries in results.items():
        eff = entries[0]["effect"]
        if name == "motor_ripple":
            # sequential greedy: the best order, then the order that adds most to it
            # (low orders alias each other over a limited angle range)
            first = max(entries, key=lambda e: e["train_gain"])
            b = rp_tr.ravel()

            def joint_gain(e):
                A = np.concatenate([first["g"], e["g"]], axis=-1).reshape(-1, 2 * first["g"].shape[-1])
                coef, *_ = np.linalg.lstsq(A, b, rcond=None)
                return float(b @ b - np.sum((b - A @ coef) ** 2))

            rest = [e for e in entries if e is not first]
            ranked = [first] + ([max(rest, key=joint_gain)] if rest else [])
            # the pair a fit resting on the amplitude bound falls back to (see ripple_pair)
            small = ripple_pair(entries, b, min_gain * max(st.E_train - st.dof[tr].sum(), 0.0))
            if {e["order"] for e in small} != {e["order"] for e in ranked}:
                fallback[name] = {f"ripple_order_{i}": e["order"] for i, e in enumerate(small, start=1)}
            cols = []
            params = {}
            for slot, e in enumerate(ranked, start=1):
                params[f"ripple_order_{slot}"] = e["order"]
                for cname, d in e["cols"]:
                    cols.append((cname.replace("1_m", f"{slot}_m"), d))
            chosen.append((eff, ranked, "orders " + ", ".join(f"{e['order']:g}" for e in ranked), params, cols))
        else:
            best = max(entries, key=lambda e: e["train_gain"])
            chosen.append((eff, [best], best["label"], best["shape"], best["cols"]))
    need = sorted({i for _, ents, *_ in chosen for e in ents
                   for i in e["sets"][0] + ([e["sets"][1]] if e["sets"][1] is not None else [])})
    R_te = dict(zip(need, eng.evaluate(np.array(Psets)[need], st.W[te]))) if need else {}
    out = []
    for eff, ents, label, shape, cols in chosen:
        gs, rps = [], []
        for e in ents:
            g_te, rp_te = signature(R_te, st.r0[te], Q_te, *e["sets"], e["cols"])
            g = np.empty((len(st.W),) + g_te.shape[1:])
            g[tr], g[te] = e["g"], g_te
            rp = np.empty((len(st.W),) + rp_te.shape[1:])
            rp[tr], rp[te] = e["rp"], rp_te
            gs.append(g)
            rps.append(rp)
        g, rp = np.concatenate(gs, axis=-1), rps[0]
        A = g[tr].reshape(-1, g.shape[-1])
        beta, *_ = np.linalg.lstsq(A, rp[tr].ravel(), rcond=None)
        fit = np.einsum("wmk,k->wm", g, beta)
        e_after = ((rp - fit) ** 2).sum(axis=1)
        gain = float(st.e[te].sum() - e_after[te].sum())
        z = paired_z(st.e[te], e_after[te])
        k = len(beta)
        rss0 = float(st.e[tr].sum())
        rss1 = float(e_after[tr].sum())
        dbic = st.n_train * math.log(max(rss1, 1e-300) / max(rss0, 1e-300)) + k * math.log(st.n_train)
        # the columns of g are sensitivities per unit parameter ((ref - R) / d above), so beta is the
        # parameter change itself: r(p + beta) ~ r(p) - g beta, minimised over beta
        params = dict(shape)
        for (cname, _), b in zip(cols, beta):
            params[cname] = float(st.base[PARAM_INDEX[cname]] + b)
        out.append(dict(effect=eff, label=label, params=params, gain=gain, z=z, dbic=dbic,
                        rel=gain / max(st.excess, 1e-12), e_after=e_after, fallback=fallback.get(eff.name)))
    probe(st, out, bounds, rig)
    out.sort(key=lambda d: -d["gain"])
    return out


PROBE_FRACTIONS = (0.03, 0.1, 0.3)  # of each amplitude's upper bound (chosen: log-spaced decade)
# effects that add states (and stiffness) to the model: profiled at their own parameters
STATEFUL_EFFECTS = {"spring_hysteresis": {"hysteresis_width": (0.05, 0.15, 0.4),
                                          "hysteresis_length": (1e-4, 3e-4, 1e-3)}}


def grid_probes(bounds: CatalogBounds) -> dict:
    """Effects whose residual is not monotone in their size (neither the linear screen nor the
    decade probes find them): ``{effect: (parameter, values)}`` probed on a geometric grid."""
    n = int(np.floor(np.log(bounds.backlash_max / bounds.backlash_probe_min) / np.log(bounds.backlash_probe_ratio)))
    return {"backlash": ("backlash", bounds.backlash_probe_min * bounds.backlash_probe_ratio ** np.arange(n + 1))}


def probe(st: ResidualState, screened: list, bounds: CatalogBounds, rig: str) -> None:
    """Nonlinear probes: effects whose signature changes with amplitude (hysteresis
    stiffening, friction sticking, delay) are also evaluated at finite amplitudes on
    their shape grid; a probe that beats the linear screen replaces its estimate."""
    eng, base = st.eng, st.base
    specs = {s.name: s for s in param_specs(bounds)}
    sets, owners = [], []
    own_sets, own_owners = [], []
    grids = grid_probes(bounds)
    for entry in screened:
        eff = entry["effect"]
        if eff.name in grids:
            name, values = grids[eff.name]
            for v in values:
                p = base.copy()
                p[PARAM_INDEX[name]] = v
                sets.append(p)
                owners.append(entry)
            continue
        if eff.name in STATEFUL_EFFECTS:
            grid = STATEFUL_EFFECTS[eff.name]
            (amp, fracs), (shp, vals) = grid.items()
            for frac in fracs:
                for v in vals:
                    p = base.copy()
                    p[PARAM_INDEX[amp]] = frac * specs[amp].high
                    p[PARAM_INDEX[shp]] = v
                    own_sets.append(p)
                    own_owners.append(entry)
            continue
        if eff.kind != "physical" or eff.name == "motor_ripple":
            continue
        shapes = [{}] if not eff.shape else [{k: g} for k, gs in eff.shape.items() for g in gs]
        for shape in shapes:
            for amp in eff.amplitude_for(rig):
                for frac in PROBE_FRACTIONS:
                    p = base.copy()
                    for k, v in shape.items():
                        p[PARAM_INDEX[k]] = v
                    p[PARAM_INDEX[amp]] = base[PARAM_INDEX[amp]] + frac * specs[amp].high
                    sets.append(p)
                    owners.append(entry)
    if not sets and not own_sets:
        return
    tr, te = eng.train, eng.test

    n_plain = len(sets)
    sets = sets + own_sets

    def energies(windows, picked, picked_own):
        """Window energies (len(picked) + len(picked_own), len(windows)) of probe sets on ``windows``:
        ``picked`` with the current model's window-start profile, ``picked_own`` with their own."""
        E = []
        if picked:
            R = eng.evaluate(np.array([sets[i] for i in picked]), st.W[windows])
            E.append((project(R, st.Q.take(st.W[windows])) ** 2).sum(axis=2))
        if picked_own:
            E.append(np.array([(project(r, Q) ** 2).sum(axis=1) for r, Q in
                               eng.profiled(np.array([sets[i] for i in picked_own]), st.W[windows])]))
        return np.concatenate(E, axis=0)

    # the best probe of each candidate is chosen on the training windows; only it is replayed on the
    # held-out windows. The stateful probes (their own window-start profile costs 1 + num_profiled_states
    # copies per window) are ranked with the current model's profile in the plain probes' pass, and only the
    # best ``bounds.stateful_probe_refine`` of each candidate are profiled at their own parameters
    E_tr = energies(tr, list(range(len(sets))), [])
    refine = []
    for entry in {id(o): o for o in own_owners}.values():
        mine = [n_plain + j for j, o in enumerate(own_owners) if o is entry]
        refine += sorted(mine, key=lambda i: E_tr[i].sum())[:bounds.stateful_probe_refine]
    E_tr[n_plain:] = np.inf
    if refine:
        E_tr[refine] = energies(tr, [], refine)
    owners = owners + own_owners
    best = {}
    for i, entry in enumerate(owners):
        key = id(entry)
        if key not in best or E_tr[i].sum() < E_tr[best[key]].sum():
            best[key] = i
    plain = sorted(i for i in set(best.values()) if i < n_plain)
    own = sorted(i for i in set(best.values()) if i >= n_plain)
    E = {}
    for i, row in zip(plain + own, energies(te, plain, own)):
        E[i] = np.empty(len(st.W))
        E[i][tr], E[i][te] = E_tr[i], row
    for entry in screened:
        i = best.get(id(entry))
        if i is None:
            continue
        lin_train = float((entry["e_after"][tr]).sum())
        if E[i][tr].sum() >= lin_train:
            continue
        gain = float(st.e[te].sum() - E[i][te].sum())
        eff = entry["effect"]
        entry["params"] = {n: float(sets[i][PARAM_INDEX[n]]) for n in free_params([eff], rig)}
        entry["gain"] = gain
        entry["rel"] = gain / max(st.excess, 1e-12)
        entry["z"] = paired_z(st.e[te], E[i][te])
        entry["e_after"] = E[i]
        entry["label"] += " (probe)"


def free_params(effects: list, rig: str) -> list:
    names = []
    for eff in effects:
        names += list(eff.amplitude_for(rig))
        names += list(eff.shape)
    seen = []
    for n in names:
        if n not in seen:
            seen.append(n)
    return seen
