"""Plots and the report folder (Markdown + PNG + JSON) of a diagnosis.

Plotting functions take results and return ``(fig, ax)``; :func:`write_report`
computes the residual maps of the nominal and the augmented model, draws them
and writes ``report.md``, ``summary.json`` and the PNGs.
"""

from __future__ import annotations

import json
import pathlib

import numpy as np

from .catalog import PARAM_UNITS, default_vector
from .localise import ResidualMaps, residual_maps
from .result import Diagnosis

__all__ = ["plot_overlay", "plot_residual_maps", "plot_candidates", "write_report", "json_summary", "findings_text"]


def _plt():
    import matplotlib
    if matplotlib.get_backend().lower() not in ("agg", "module://matplotlib_inline.backend_inline"):
        try:
            matplotlib.use("Agg")
        except Exception:  # pragma: no cover
            pass
    import matplotlib.pyplot as plt
    return plt


def plot_overlay(dx: Diagnosis, *, windows: int = 4):
    """Measured vs nominal vs augmented predictions on held-out windows (one row per signal)."""
    plt = _plt()
    eng = dx.engine
    test = np.nonzero(eng.test)[0]
    pick = test[np.linspace(0, len(test) - 1, min(windows, len(test))).astype(int)]
    ny = len(eng.out_names)
    fig, ax = plt.subplots(ny, len(pick), figsize=(2.6 * len(pick) + 1, 1.8 * ny), sharex="col",
                           squeeze=False)
    preds = {}
    for label, p in (("nominal", default_vector()), ("augmented", dx.final_parameters)):
        # prediction from the profiled window start: measured - (residual - MAP correction)
        r0, proj = eng.projector(p, pick)
        shift = (r0 - proj.correction(r0)).reshape(len(pick), eng.L, ny) * eng.sigma
        idx = eng.starts[pick][:, None] + 1 + np.arange(eng.L)[None, :]
        preds[label] = eng.Y[idx] - shift
    for w_i, w in enumerate(pick):
        idx = eng.starts[w] + 1 + np.arange(eng.L)
        t = eng.ds.time[idx]
        for j, name in enumerate(eng.out_names):
            a = ax[j, w_i]
            a.plot(t, preds["nominal"][w_i, :, j], color="C3", lw=1, label="nominal", zorder=1)
            a.plot(t, preds["augmented"][w_i, :, j], color="C0", lw=1, label="augmented", zorder=2)
            # measured last and on top: the models are judged against it
            a.plot(t, eng.Y[idx, j], ".", color="k", ms=1.5, label="measured", zorder=3)
            a.tick_params(labelsize=6)
            if w_i == 0:
                a.set_ylabel(name, fontsize=7)
        ax[-1, w_i].set_xlabel("time [s]", fontsize=7)
    ax[0, 0].legend(fontsize=6)
    fig.suptitle(f"{dx.dataset}: held-out windows replayed from the profiled window starts", fontsize=9)
    fig.tight_layout()
    return fig, ax


def plot_residual_maps(maps: ResidualMaps, title: str = ""):
    """Eight panels: spectrum/floor, coherence, cycles per rev, lag; residual by velocity,
    motor angle, tendon force and direction of elongation (operating regions)."""
    plt = _plt()
    fig, ax = plt.subplots(2, 4, figsize=(15, 6.5))
    ax = ax.ravel()
    for n, p in maps.psd_ratio.items():
        ax[0].semilogy(maps.freq, np.maximum(p, 1e-3), lw=0.8, label=n)
    ax[0].axhline(1.0, color="k", ls="--", lw=0.8)
    ax[0].set(xlabel="frequency [Hz]", ylabel="residual PSD / noise floor", title="spectrum")
    ax[0].legend(fontsize=6)
    for (n, u), c in maps.coherence.items():
        ax[1].plot(maps.freq, c, lw=0.6, label=f"{n} | {u}")
    ax[1].set(xlabel="frequency [Hz]", ylabel="coherence", title="residual-input coherence", ylim=(0, 1))
    ax[1].legend(fontsize=5)
    for n, a in maps.cpr_amplitude.items():
        ax[2].plot(maps.cpr_orders, a, lw=0.7, label=n)
    ax[2].axhline(3.0 * maps.cpr_noise, color="k", ls="--", lw=0.8, label="3x noise amplitude")
    ax[2].set(xlabel="cycles per motor revolution", ylabel="amplitude [noise units]",
              title="residual vs motor angle", xlim=(0, maps.cpr_orders[-1]))
    ax[2].legend(fontsize=5)
    for n, v in maps.velocity_profile.items():
        ax[3].plot(maps.velocity_bins, v, "o-", ms=3, lw=0.8, label=n)
    ax[3].axhline(0, color="k", lw=0.5)
    ax[3].set(xlabel="motor velocity bin centre [rad/s]", ylabel="mean residual [noise units]",
              title="by velocity")
    for a, (bins, prof, label) in zip((ax[6], ax[7]), ((maps.position_bins, maps.position_profile,
                                                         "motor angle bin centre [rad]"),
                                                        (maps.force_bins, maps.force_profile,
                                                         "tendon force bin centre [N]"))):
        for n, v in prof.items():
            a.plot(bins, v, "o-", ms=3, lw=0.8, label=n)
        if a is ax[6] and maps.link_bins is not None:   # the link angle on the same radian axis (joint rig)
            for n, v in maps.link_profile.items():
                a.plot(maps.link_bins, v, "s--", ms=3, lw=0.8, label=f"{n} (by link angle)")
            label = "motor / link angle bin centre [rad]"
        a.axhline(0, color="k", lw=0.5)
        a.set(xlabel=label, ylabel="mean residual [noise units]", title="by " + label.split(" bin")[0])
    names = list(maps.direction_asymmetry)
    ax[4].bar(range(len(names)), [maps.direction_asymmetry[n] for n in names])
    ax[4].set_xticks(range(len(names)), names, fontsize=7)
    ax[4].set(ylabel="res(x'>0) - res(x'<0) [noise units]", title="by direction of elongation")
    for n, c in maps.xcorr.items():
        ax[5].plot(maps.lags * 1e3, c, lw=0.8, label=n)
    ax[5].set(xlabel="lag [ms]", ylabel="corr(residual, du/dt)", title="residual-input lag")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig, ax


def plot_candidates(dx: Diagnosis):
    """Held-out gain (share of the energy above the noise floor) of the candidates per step."""
    plt = _plt()
    nstep = max(len(dx.history), 1)
    fig, ax = plt.subplots(1, nstep, figsize=(5 * nstep, 3.2), squeeze=False)
    ax = ax[0]
    for i, h in enumerate(dx.history):
        sc = h["screen"]
        names = [c["effect"] for c in sc]
        ax[i].barh(range(len(sc)), [100 * c["relative_gain"] for c in sc], color="0.7", label="screen")
        fits = {c["effect"]: c for c in h["fits"]}
        ax[i].barh([names.index(k) for k in fits], [100 * c["relative_gain"] for c in fits.values()],
                   height=0.4, color="C0", label="simulation fit")
        ax[i].set_yticks(range(len(sc)), names, fontsize=7)
        ax[i].invert_yaxis()
        ax[i].set(xlabel="held-out gain [% of excess over floor]",
                  title=f"step {i + 1} (residual/floor {h['ratio']:.2f})")
        ax[i].legend(fontsize=7)
    fig.tight_layout()
    return fig, ax


def plot_finger_tendons(dx):
    """Held-out residual / noise floor per tendon, motor side, before and after the named effects (bars),
    the places named marked; returns ``(fig, ax)``."""
    plt = _plt()
    names = dx.tendon_names
    x = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(7, 3))
    ax.bar(x - 0.2, dx.ratios_before["motor"], 0.4, label="nominal")
    ax.bar(x + 0.2, dx.ratios_after["motor"], 0.4, label="with the named effects")
    ax.axhline(1.0, color="k", lw=0.8, ls=":")
    ax.set_yscale("log")
    ax.set_xticks(x, [n + (" *" if any(s.tendon == i + 1 for s in dx.steps) else "") for i, n in enumerate(names)],
                  rotation=30, fontsize=8)
    ax.set_ylabel("residual / noise floor")
    ax.set_title(f"{dx.dataset}: motor side per tendon (* named)", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig, ax


def _write_finger_report(dx, directory, figures: bool) -> pathlib.Path:
    plt = _plt()
    d = pathlib.Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    if figures:
        fig = plot_finger_tendons(dx)[0]
        fig.savefig(d / "tendons.png", dpi=110)
        plt.close(fig)
    (d / "summary.json").write_text(json.dumps(dx.summary(), indent=1, default=float))
    if dx.augmented is not None:    # the write-back: FingerRigParams for finger_diagram(params=...) / --config
        from awiwi_drake.parameters.yaml_io import save_yaml
        save_yaml(dx.augmented.params, d / "augmented_parameters.yaml")
    L = [f"# Model-discrepancy diagnosis: {dx.dataset}", "", f"Rig `{dx.rig}`; verdict: **{dx.verdict}**.", "",
         "Motor side (motor law with the measured tendon force) and spring side (spring laws, joint angles "
         "estimated from all tendons), consistent filtering, blocked 3-fold cross-validation "
         "(`awiwi_drake.discrepancy.finger`).", "",
         "| tendon | motor side before | after | spring side before |", "|---|---|---|---|"]
    for i, n in enumerate(dx.tendon_names):
        L.append(f"| {n} | {dx.ratios_before['motor'][i]:.2f} | {dx.ratios_after['motor'][i]:.2f} | "
                 f"{dx.ratios_before['spring'][i]:.2f} |")
    L += ["", f"Spring side, all tendons: {dx.ratios_before['spring_total']:.2f} before, "
          f"{dx.ratios_after['spring_total']:.2f} after (1 = the noise floor).", "",
          "![tendons](tendons.png)" if figures else "", "", "## Findings", "", findings_text(dx), "",
          "## Augmented parameters", "",
          ("`augmented_parameters.yaml`: the dataset's `HandRigParams` with the named effects written "
           "(`load_yaml(HandRigParams(), path)` -> `hand_diagram(params=...)`). Written: " if dx.rig == "hand" else
           "`augmented_parameters.yaml`: the dataset's `FingerRigParams` with the named effects written "
           "(`load_yaml(FingerRigParams.for_finger(...), path)` -> `finger_diagram(params=...)`). Written: ")
          + (", ".join(dx.augmented.applied) or "nothing") + "."
          + ("" if not dx.augmented.not_representable else
             " Not representable: " + "; ".join(dx.augmented.not_representable) + "."), "", "## Steps", ""]
    for k, st in enumerate(dx.steps, 1):
        L.append(f"{k}. `{st.effect}` on {st.place} ({st.kind}, {st.status}; held-out gain {st.z:.1f} null std, "
                 f"dBIC {st.delta_bic:.0f}): " + ", ".join(f"`{p}` = {v:.4g} {PARAM_UNITS.get(p, '')}".rstrip()
                                                            for p, v in st.parameters.items()))
        if st.status == "not separable":
            L.append(f"   Not separable with these data from {', '.join(st.members[1:])}: {st.experiment}.")
    md = d / "report.md"
    md.write_text("\n".join(L) + "\n")
    return md


def json_summary(dx: Diagnosis, maps_before: ResidualMaps | None = None) -> dict:
    """The JSON summary (contract keys: named_effects, nrmse_before, nrmse_after, steps)."""
    if not isinstance(dx, Diagnosis):   # a finger diagnosis (awiwi_drake.discrepancy.finger)
        return dx.summary()
    out = dx.to_json()
    out["units"] = {k: PARAM_UNITS.get(k, "?") for st in dx.steps for k in st.parameters}  # of every fitted value
    if maps_before is not None:
        out["localisation"] = maps_before.summary
    return out


def findings_text(dx: Diagnosis) -> str:
    """One paragraph on what the diagnosis found and what is left (report and CLI)."""
    if not isinstance(dx, Diagnosis):   # a finger diagnosis
        if dx.unexplained_residual:
            return (f"Unexplained discrepancy remains: {dx.unexplained['text']} (threshold "
                    f"{dx.unexplained_ratio:g}x); the catalog does not explain it.")
        if dx.steps:
            return (f"After the named steps every tendon's held-out residual is below {dx.unexplained_ratio:g}x "
                    f"its noise floor.")
        return f"No tendon's held-out residual is above {dx.unexplained_ratio:g}x its noise floor: nothing named."
    if dx.unexplained_residual:
        out = (f"Unexplained discrepancy remains: after the last accepted step the held-out residual is "
               f"{dx.floor_ratio_after:.2f}x the noise floor (threshold {dx.unexplained_ratio:g}x); the "
               "catalog does not explain it.")
        if dx.unexplained:
            out += f" Where: {dx.unexplained['text']}."
        return out
    if dx.steps:
        return (f"The held-out residual is {dx.floor_ratio_after:.2f}x the noise floor after the named steps "
                f"(below the {dx.unexplained_ratio:g}x threshold for an unexplained discrepancy).")
    if dx.stop_reason.startswith("residual at the noise floor"):
        return "The nominal model's residual is at the noise floor: nothing is missing from the model."
    return (f"No catalog candidate passed the acceptance tests; the residual is {dx.floor_ratio_after:.2f}x "
            f"the noise floor, below the {dx.unexplained_ratio:g}x threshold for an unexplained discrepancy.")


def write_report(dx: Diagnosis, directory, *, figures: bool = True) -> pathlib.Path:
    """Write ``report.md``, ``summary.json`` and (with ``figures``) PNGs into ``directory``;
    returns the Markdown path.  ``figures=False`` simulates nothing (used for the partial
    report of an interrupted run)."""
    if not isinstance(dx, Diagnosis):   # a finger diagnosis
        return _write_finger_report(dx, directory, figures)
    plt = _plt()
    d = pathlib.Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    eng = dx.engine
    maps0 = None
    if figures:
        maps0 = residual_maps(eng, default_vector())
        maps1 = residual_maps(eng, dx.final_parameters)
        figs = {
            "overlay.png": plot_overlay(dx)[0],
            "residual_maps_nominal.png": plot_residual_maps(maps0, "nominal model residual")[0],
            "residual_maps_augmented.png": plot_residual_maps(maps1, "augmented model residual")[0],
        }
        if dx.history:
            figs["candidates.png"] = plot_candidates(dx)[0]
        for name, fig in figs.items():
            fig.savefig(d / name, dpi=110)
            plt.close(fig)
    summary = json_summary(dx, maps0)
    (d / "summary.json").write_text(json.dumps(summary, indent=1, default=float))
    L = [f"# Model-discrepancy diagnosis: {dx.dataset}", "",
         f"Rig `{dx.rig}`; verdict: **{dx.verdict}**; "
         f"named effects: {', '.join(f'`{e}`' + (f' on {dx.places[e]}' if e in dx.places else '') for e in dx.named_effects) or 'none'}"
         + (f"; calibration: {', '.join(dx.nuisance_corrections)}" if dx.nuisance_corrections else "")
         + f". {dx.simulations} batched Drake simulations, {dx.seconds:.1f} s.", "",
         "## Gap (held-out multiple-shooting windows)", "",
         "| signal | noise floor | NRMSE before | NRMSE after | fit % before | fit % after |",
         "|---|---|---|---|---|---|"]
    for n in dx.nrmse_before_signals:
        b, a = dx.nrmse_before_signals[n], dx.nrmse_after_signals[n]
        L.append(f"| `{n}` | {dx.noise_floor[n]:.3g} | {b:.4f} | {a:.4f} | {100 * (1 - b):.1f} | {100 * (1 - a):.1f} |")
    L += [f"| **mean** | | {dx.nrmse_before:.4f} | {dx.nrmse_after:.4f} | {dx.fit_percent_before:.1f} | "
          f"{dx.fit_percent_after:.1f} |", "",
          f"Residual energy / noise floor on held-out windows: {dx.floor_ratio_before:.3f} before, "
          f"{dx.floor_ratio_after:.3f} after (1 = nothing left to explain).", "",
          "![overlay](overlay.png)" if figures else "", "", "## Findings", "", findings_text(dx), "",
          "## Steps", ""]
    if not dx.complete:
        L += ["", "**Partial result**: the run was interrupted; steps below are those accepted so far.", ""]
    if dx.stop_reason:
        L += ["", f"Stopped: {dx.stop_reason}.", ""]
    for i, s in enumerate(dx.steps, 1):
        L.append(f"### {i}. `{s.effect}` ({s.kind}, {s.status}, confidence {s.confidence:.2f})")
        L.append("")
        L.append("| parameter | value | std. error | unit |")
        L.append("|---|---|---|---|")
        for k, v in s.parameters.items():
            L.append(f"| `{k}` | {v:.5g} | {s.uncertainties.get(k, float('nan')):.2g} | {PARAM_UNITS.get(k, '?')} |")
        L.append("")
        L.append(f"NRMSE after: {s.nrmse_after:.4f}." + (f" Alternatives: {s.alternatives}." if s.alternatives else ""))
        if s.status == "not separable":
            L += ["", f"Not separable with these data: {', '.join(f'`{m}`' for m in s.members)} explain the "
                  f"same residual (listed: lowest BIC first). Suggested experiment: {s.experiment}."]
        L.append("")
        L.append("| candidate | stage | held-out gain [% excess] | z | dBIC | parameters | rejected |")
        L.append("|---|---|---|---|---|---|---|")
        for c in s.candidates:
            ps = ", ".join(f"{k}={v:.3g} {PARAM_UNITS.get(k, '?')}" for k, v in c.parameters.items())
            L.append(f"| {c.effect} | {c.stage} | {100 * c.relative_gain:.1f} | {c.z:.1f} | {c.delta_bic:.0f} | {ps} "
                     f"| {c.rejected} |")
        L.append("")
    if figures:
        L += ["## Residual maps", "", "Nominal model:", "", "![nominal](residual_maps_nominal.png)", "",
              "Augmented model:", "", "![augmented](residual_maps_augmented.png)", ""]
        if dx.history:
            L += ["## Candidates", "", "![candidates](candidates.png)", ""]
        L += ["## Localisation (nominal residual)", "", "```", json.dumps(maps0.summary, indent=1, default=float),
              "```", ""]
    L += ["Standard errors assume white residuals (they understate the uncertainty when "
          "the residual is coloured).", ""]
    md = d / "report.md"
    md.write_text("\n".join(L))
    return md
