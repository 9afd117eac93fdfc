"""``awiwi-drake diagnose`` and ``awiwi-drake make-dataset``: the model-discrepancy workflow.

``diagnose NAME.csv [--report DIR] [--json OUT.json]`` finds, names and adds
missing effects (progress on stderr, summary on stdout).
``make-dataset --rig joint --hide joint_friction --out DIR`` writes a
hidden-effect truth dataset (NAME.csv + NAME.json).
"""

from __future__ import annotations

import json
import sys

__all__ = ["register"]


def _diagnose(args) -> int:
    from awiwi_drake.discrepancy import DiagnosisInterrupted, diagnose, load_dataset
    from awiwi_drake.discrepancy.report import findings_text, json_summary, write_report
    from awiwi_drake.parameters.discrepancy import DiscrepancySettings

    from . import parse_sets

    ds = load_dataset(args.dataset)
    settings = DiscrepancySettings().with_overrides(parse_sets(args.set))
    progress = None if args.quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))

    def write_json(dx):
        if args.json:
            with open(args.json, "w") as fh:
                json.dump(json_summary(dx), fh, indent=1, default=float)

    try:
        dx = diagnose(ds, settings=settings, progress=progress, checkpoint=write_json)
    except DiagnosisInterrupted as exc:
        dx = exc.diagnosis
        write_json(dx)
        if args.report:
            write_report(dx, args.report, figures=False)
        print(f"{dx.dataset}: interrupted after {len(dx.steps)} accepted step(s); partial summary written"
              + (f" to {args.json}" if args.json else "") + (f" and {args.report}" if args.report else ""),
              file=sys.stderr)
        return 130
    if args.report:
        md = write_report(dx, args.report)
        print(f"report: {md}", file=sys.stderr)
    write_json(dx)
    named = ", ".join(dx.named_effects) or "none"
    print(f"{dx.dataset}: {dx.verdict}; named effects: {named}")
    if dx.nuisance_corrections:
        print(f"calibration corrections: {', '.join(dx.nuisance_corrections)}")
    for s in dx.steps:
        ps = ", ".join(f"{k}={v:.4g}" for k, v in s.parameters.items())
        print(f"  {s.effect} [{s.status}, confidence {s.confidence:.2f}]: {ps}")
        if s.status == "not separable":
            print(f"    not separable with these data from {', '.join(s.members[1:])}; "
                  f"to separate them: {s.experiment}")
    print(findings_text(dx))
    print(f"NRMSE {dx.nrmse_before:.4f} -> {dx.nrmse_after:.4f} "
          f"(fit {dx.fit_percent_before:.1f}% -> {dx.fit_percent_after:.1f}%)")
    return 0


def _make_dataset(args) -> int:
    from awiwi_drake.discrepancy import make_truth_dataset, save_dataset
    from awiwi_drake.parameters.discrepancy import TruthGeneratorParams

    hidden = []
    for h in args.hide or []:
        hidden += [x.strip() for x in h.split(",") if x.strip() and x.strip() != "none"]
    nuisance = []
    for h in args.nuisance or []:
        nuisance += [x.strip() for x in h.split(",") if x.strip()]
    gen = TruthGeneratorParams()
    if args.duration is not None:
        gen = gen.replace(duration=args.duration)
    snr = None if args.snr.lower() in ("inf", "none") else float(args.snr)
    ds = make_truth_dataset(args.rig, hidden, snr_db=snr, seed=args.seed, nuisance=nuisance, gen=gen,
                            name=args.name, keep_clean=False)
    path = save_dataset(ds, args.out)
    print(f"{path} (+ .json): rig {args.rig}, hidden {hidden or 'none'}, SNR {args.snr} dB, seed {args.seed}")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser("diagnose", help="find, name and add missing effects in a dataset",
                              description=__doc__)
    p.add_argument("dataset", help="NAME.csv (with NAME.json beside it)")
    p.add_argument("--report", metavar="DIR", help="write report.md, PNGs and summary.json here")
    p.add_argument("--json", metavar="OUT.json", help="write the JSON summary here")
    p.add_argument("--set", action="append", metavar="NAME=VALUE",
                   help="override a DiscrepancySettings field (e.g. window=0.05)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=_diagnose)

    m = subparsers.add_parser("make-dataset", help="generate a hidden-effect truth dataset")
    m.add_argument("--rig", choices=["tendon", "joint"], default="joint")
    m.add_argument("--hide", action="append", metavar="EFFECT",
                   help="catalog effect hidden in the truth (repeat or comma-separate; 'none')")
    m.add_argument("--nuisance", action="append", metavar="NAME",
                   help="miscalibration in the truth: force_sensor, nominal_motor")
    m.add_argument("--snr", default="30", help="sensor SNR in dB ('inf' for noise-free)")
    m.add_argument("--seed", type=int, default=0)
    m.add_argument("--duration", type=float, default=None, help="seconds (default 10)")
    m.add_argument("--name", default=None, help="file stem (default from rig/effects/SNR/seed)")
    m.add_argument("--out", required=True, metavar="DIR")
    m.set_defaults(func=_make_dataset)
