"""Benchmark of the model-discrepancy workflow on hidden-effect truth datasets.

For each dataset (random physical parameters, closed-loop lab excitation, sensor
noise at a given SNR, 12-bit force quantisation, 0, 1 or 2 hidden effects in
truth forms that differ from the catalog forms) the workflow is run and scored:

* top-1 naming rate: the first physical effect named is the hidden one (1 hidden);
* false-positive rate: any physical effect named when nothing is hidden;
* exact-set rate: the named set equals the hidden set (2 hidden);
* gap closed on held-out windows: (E_nominal - E_augmented) / (E_nominal - E_truth);
* seconds per diagnosis (10 s joint dataset at 1 kHz, whole catalog).

Usage::

    PYTHONPATH=. python benchmarks/bench_discrepancy.py [--quick] [--seeds N] [--jobs J] [--out DIR]

Writes ``discrepancy_benchmark.json`` and ``discrepancy_benchmark.md`` into
``--out`` (default ``$AWIWI_OUT`` or ``out/bench_discrepancy``).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

SINGLE = ["motor_friction", "motor_ripple", "spring_hysteresis", "joint_friction", "guide_friction", "delay"]
PAIRS = [("motor_friction", "delay"), ("joint_friction", "motor_ripple"), ("spring_hysteresis", "motor_friction"),
         ("guide_friction", "joint_friction"), ("motor_ripple", "delay"), ("spring_hysteresis", "joint_friction")]


def cases(seeds: int, quick: bool) -> list:
    out = []
    snrs = (40, 30, 20)
    if quick:
        return [("joint", ["joint_friction"], 30, 1, ()), ("joint", [], 30, 2, ()),
                ("tendon", ["delay"], 30, 3, ()), ("joint", ["motor_friction", "delay"], 30, 4, ())]
    seed = 100
    for s in range(seeds):
        for eff in SINGLE:
            for snr in snrs:
                seed += 1
                out.append(("joint", [eff], snr, seed, ()))
        for snr in snrs:
            for _ in range(2):
                seed += 1
                out.append(("joint", [], snr, seed, ()))
        for pair in PAIRS:
            seed += 1
            out.append(("joint", list(pair), 30, seed, ()))
        for eff in ("motor_friction", "delay", "spring_hysteresis"):
            seed += 1
            out.append(("tendon", [eff], 30, seed, ()))
        seed += 1
        out.append(("joint", [], 30, seed, ("force_sensor",)))
    return out


def run_case(case) -> dict:
    from awiwi_drake.discrepancy import diagnose, make_truth_dataset
    from awiwi_drake.discrepancy.workflow import gap_metrics

    rig, hidden, snr, seed, nuisance = case
    t0 = time.perf_counter()
    ds = make_truth_dataset(rig, hidden, snr_db=snr, seed=seed, nuisance=nuisance)
    t_gen = time.perf_counter() - t0
    dx = diagnose(ds)
    gap = gap_metrics(dx, ds)
    return {"rig": rig, "hidden": list(hidden), "snr_db": snr, "seed": seed, "nuisance": list(nuisance),
            "named": dx.named_effects, "nuisance_named": dx.nuisance_corrections,
            "confidence": [s.confidence for s in dx.steps if s.kind == "physical"],
            "status": [s.status for s in dx.steps], "nrmse_before": dx.nrmse_before,
            "nrmse_after": dx.nrmse_after, "seconds": dx.seconds, "cpu_seconds": dx.cpu_seconds, "generate_seconds": t_gen,
            "simulations": dx.simulations, **gap}


def summarise(rows: list) -> dict:
    def rate(sel, ok):
        sel = [r for r in rows if sel(r)]
        return (float(np.mean([ok(r) for r in sel])) if sel else float("nan")), len(sel)

    summ = {"top1": {}, "top1_by_snr": {}, "false_positive": {}, "exact_set": {}, "gap_closed": {}}
    one = lambda r: len(r["hidden"]) == 1  # noqa: E731
    for eff in SINGLE:
        for snr in (40, 30, 20):
            v, n = rate(lambda r: one(r) and r["hidden"][0] == eff and r["snr_db"] == snr and r["rig"] == "joint",
                        lambda r: bool(r["named"]) and r["named"][0] == r["hidden"][0])
            if n:
                summ["top1"][f"{eff}@{snr}"] = (v, n)
    for snr in (40, 30, 20):
        summ["top1_by_snr"][snr] = rate(lambda r: one(r) and r["snr_db"] == snr,
                                        lambda r: bool(r["named"]) and r["named"][0] == r["hidden"][0])
        summ["false_positive"][snr] = rate(lambda r: not r["hidden"] and r["snr_db"] == snr,
                                           lambda r: bool(r["named"]))
    summ["exact_set"]["two_hidden"] = rate(lambda r: len(r["hidden"]) == 2,
                                           lambda r: sorted(r["named"]) == sorted(r["hidden"]))
    gaps = [r["gap_closed"] for r in rows if r["hidden"]]
    summ["gap_closed"] = {"median": float(np.median(gaps)) if gaps else float("nan"),
                          "mean": float(np.mean(gaps)) if gaps else float("nan"),
                          "fraction_ge_0.8": float(np.mean(np.array(gaps) >= 0.8)) if gaps else float("nan")}
    joint = [r["seconds"] for r in rows if r["rig"] == "joint"]
    cpu = [r["cpu_seconds"] for r in rows if r["rig"] == "joint"]
    summ["seconds_joint"] = {"median": float(np.median(joint)), "max": float(np.max(joint)),
                             "cpu_median": float(np.median(cpu)), "cpu_max": float(np.max(cpu))} if joint else {}
    summ["datasets"] = len(rows)
    return summ


def markdown(summ: dict, rows: list) -> str:
    L = ["| metric | value | datasets | target |", "|---|---|---|---|"]
    for snr, (v, n) in summ["top1_by_snr"].items():
        tgt = ">= 90 %" if snr >= 30 else ">= 75 %"
        L.append(f"| top-1 naming, {snr} dB | {100 * v:.0f} % | {n} | {tgt} |")
    for snr, (v, n) in summ["false_positive"].items():
        L.append(f"| false positive (nothing hidden), {snr} dB | {100 * v:.0f} % | {n} | <= 5 % |")
    v, n = summ["exact_set"]["two_hidden"]
    L.append(f"| exact set, two hidden | {100 * v:.0f} % | {n} | >= 75 % |")
    g = summ["gap_closed"]
    L.append(f"| gap closed (held out), median / mean | {g['median']:.2f} / {g['mean']:.2f} | "
             f"{sum(1 for r in rows if r['hidden'])} | >= 0.8 |")
    if summ["seconds_joint"]:
        sj = summ["seconds_joint"]
        L.append(f"| wall seconds per 10 s joint diagnosis (shared machine), median / max | {sj['median']:.1f} / "
                 f"{sj['max']:.1f} | | < 60 |")
        L.append(f"| CPU seconds per 10 s joint diagnosis, median / max | {sj['cpu_median']:.1f} / "
                 f"{sj['cpu_max']:.1f} | | < 60 |")
    L += ["", "| effect @ SNR | top-1 | datasets |", "|---|---|---|"]
    for k, (v, n) in summ["top1"].items():
        L.append(f"| {k} | {100 * v:.0f} % | {n} |")
    L += ["", "| rig | hidden | SNR | named | calibration | gap closed | wall s | CPU s |",
          "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        L.append(f"| {r['rig']} | {', '.join(r['hidden']) or '-'}{' +' + ','.join(r['nuisance']) if r['nuisance'] else ''} "
                 f"| {r['snr_db']} | {', '.join(r['named']) or '-'} | {', '.join(r['nuisance_named']) or '-'} "
                 f"| {r['gap_closed']:.2f} | {r['seconds']:.1f} | {r['cpu_seconds']:.1f} |".replace(
                     f"| {r['gap_closed']:.2f} |", "| - |" if not r["hidden"] else f"| {r['gap_closed']:.2f} |"))
    return "\n".join(L)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="4 datasets (smoke run)")
    ap.add_argument("--seeds", type=int, default=1, help="repetitions of the full design (30 datasets each)")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", default=os.environ.get("AWIWI_OUT", "out/bench_discrepancy"))
    args = ap.parse_args(argv)
    todo = cases(args.seeds, args.quick)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    t0 = time.perf_counter()
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as ex:
            for i, r in enumerate(ex.map(run_case, todo)):
                rows.append(r)
                print(f"[{i + 1}/{len(todo)}] {r['rig']} {r['hidden']} {r['snr_db']} dB -> {r['named']} "
                      f"gap {r['gap_closed']:.2f} ({r['seconds']:.1f} s)", flush=True)
    else:
        for i, c in enumerate(todo):
            r = run_case(c)
            rows.append(r)
            print(f"[{i + 1}/{len(todo)}] {r['rig']} {r['hidden']} {r['snr_db']} dB -> {r['named']} "
                  f"gap {r['gap_closed']:.2f} ({r['seconds']:.1f} s)", flush=True)
            (out / "discrepancy_benchmark_rows.json").write_text(json.dumps(rows, indent=1, default=float))
    summ = summarise(rows)
    summ["wall_seconds"] = time.perf_counter() - t0
    (out / "discrepancy_benchmark.json").write_text(json.dumps({"summary": summ, "rows": rows}, indent=1,
                                                               default=float))
    md = markdown(summ, rows)
    (out / "discrepancy_benchmark.md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
