"""Localise a residual: signals, frequency bands, angle periodicity, operating regions, lag.

Works on the multiple-shooting residual of a model (windows stitched back into
time order) in noise-floor units, so "1" is the noise floor everywhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import coherence, welch

from .replay import ReplayEngine, project

__all__ = ["ResidualMaps", "residual_maps"]


@dataclass
class ResidualMaps:
    """Residual maps of one model on one dataset (arrays for plots, numbers for JSON)."""

    t: np.ndarray
    residual: dict  # signal -> (N,) normalised residual, NaN outside windows
    freq: np.ndarray
    psd_ratio: dict  # signal -> PSD / noise-floor PSD
    coherence: dict  # (signal, input) -> coherence
    cpr_orders: np.ndarray
    cpr_amplitude: dict  # signal -> amplitude per order (noise units)
    cpr_noise: float
    velocity_bins: np.ndarray
    velocity_profile: dict  # signal -> mean residual per motor-velocity bin
    position_bins: np.ndarray
    position_profile: dict  # signal -> mean residual per motor-angle bin
    force_bins: np.ndarray | None
    force_profile: dict  # signal -> mean residual per tendon-force bin
    direction_asymmetry: dict  # force signal -> mean(res | x' > 0) - mean(res | x' < 0) (noise units)
    lags: np.ndarray
    xcorr: dict  # signal -> normalised cross-correlation with the first input's rate
    summary: dict


def residual_maps(eng: ReplayEngine, params: np.ndarray) -> ResidualMaps:
    """Compute the maps of the model with catalog parameters ``params``."""
    W = np.arange(len(eng.starts))
    r0, Q = eng.projector(params, W)
    rp = project(r0, Q)
    ny = len(eng.out_names)
    N, fs = eng.N, 1.0 / eng.dt
    full = np.full((N, ny), np.nan)
    idx = eng.starts[:, None] + 1 + np.arange(eng.L)[None, :]
    full[idx.ravel()] = rp.reshape(-1, ny)
    ok = ~np.isnan(full[:, 0])
    res = {n: full[:, j] for j, n in enumerate(eng.out_names)}
    nper = int(min(1024, ok.sum() // 4))
    nper = max(nper, 16)
    psd_ratio, coh = {}, {}
    freq = None
    for j, n in enumerate(eng.out_names):
        x = full[ok, j]
        freq, p = welch(x, fs=fs, nperseg=nper)
        psd_ratio[n] = p / (2.0 / fs)
        for i, u in enumerate(eng.ds.spec.inputs):
            _, c = coherence(x, eng.U[ok, i], fs=fs, nperseg=nper)
            coh[(n, u)] = c
    # periodicity in motor angle (cycles per revolution of the output shaft)
    nmot = eng.nom.num_motors
    theta = eng.xhat[0][ok]
    orders = np.array([1, 2, 3, 4, 5, 6, 8, 100])
    cpr = {}
    for j, n in enumerate(eng.out_names):
        x = full[ok, j]
        amps = []
        for k in orders:
            A = np.column_stack([np.sin(k * theta), np.cos(k * theta), np.ones_like(theta)])
            c, *_ = np.linalg.lstsq(A, x, rcond=None)
            amps.append(float(np.hypot(c[0], c[1])))
        cpr[n] = np.array(amps)
    cpr_noise = float(2.0 / np.sqrt(max(ok.sum(), 1)))
    # operating regions: quantile bins of motor velocity, motor angle and tendon force
    def profile(v):
        edges = np.quantile(v, np.linspace(0, 1, 11))
        bins = np.clip(np.searchsorted(edges, v) - 1, 0, 9)
        prof = {n: np.array([np.mean(full[ok, j][bins == b]) if np.any(bins == b) else np.nan
                             for b in range(10)]) for j, n in enumerate(eng.out_names)}
        return 0.5 * (edges[1:] + edges[:-1]), prof

    centers, vprof = profile(eng.xhat[nmot][ok])
    pos_centers, pprof = profile(theta)
    fkey = next((o for o in eng.out_names if o.startswith("tendon_force")), None)
    force_centers, fprof = profile(eng.ds.outputs[fkey][ok]) if fkey else (None, {})
    # direction of elongation
    xd = np.array([eng.elong[i] for i in range(nmot)])
    xdd = np.gradient(xd, axis=1)[:, ok]
    asym = {}
    for j, n in enumerate(eng.out_names):
        if n.startswith("tendon_force"):
            i = 0 if n in ("tendon_force", "tendon_force_1") else 1
            x = full[ok, j]
            asym[n] = float(np.mean(x[xdd[i] > 0]) - np.mean(x[xdd[i] < 0]))
    # lag of the residual / input-rate cross-correlation
    du = np.gradient(eng.U[:, 0])[ok]
    du = (du - du.mean()) / (du.std() + 1e-300)
    maxlag = int(min(30, ok.sum() // 4))
    lags = np.arange(-maxlag, maxlag + 1)
    xc = {}
    for j, n in enumerate(eng.out_names):
        x = full[ok, j]
        x = (x - x.mean()) / (x.std() + 1e-300)
        xc[n] = np.array([np.mean(x[max(0, l):len(x) + min(0, l)] * du[max(0, -l):len(du) - max(0, l)])
                          for l in lags])
    excess = {n: float(np.nanmean(res[n] ** 2)) for n in eng.out_names}
    worst = max(excess, key=excess.get)
    band = freq[np.argmax(psd_ratio[worst])]
    top_order = {n: int(orders[np.argmax(cpr[n])]) for n in eng.out_names}
    summary = {
        "energy_per_signal": excess,
        "worst_signal": worst,
        "peak_excess_frequency_hz": float(band),
        "max_coherence": {f"{a}|{b}": float(np.max(c)) for (a, b), c in coh.items()},
        "top_cpr_order": top_order,
        "top_cpr_amplitude": {n: float(np.max(cpr[n])) for n in eng.out_names},
        "cpr_noise_amplitude": cpr_noise,
        "velocity_sign_asymmetry": {n: float(np.nanmean(v[5:]) - np.nanmean(v[:5])) for n, v in vprof.items()},
        "position_trend": {n: float(np.nanmean(v[5:]) - np.nanmean(v[:5])) for n, v in pprof.items()},
        "force_trend": {n: float(np.nanmean(v[5:]) - np.nanmean(v[:5])) for n, v in fprof.items()},
        "direction_asymmetry": asym,
        "xcorr_peak_lag_s": {n: float(lags[np.argmax(np.abs(c))] * eng.dt) for n, c in xc.items()},
    }
    return ResidualMaps(eng.ds.time, res, freq, psd_ratio, coh, orders, cpr, cpr_noise, centers, vprof,
                        pos_centers, pprof, force_centers, fprof,
                        asym, lags * eng.dt, xc, summary)
