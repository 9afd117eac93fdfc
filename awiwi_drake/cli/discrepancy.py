"""``awiwi-drake diagnose`` and ``awiwi-drake make-dataset``: the model-discrepancy workflow.

``diagnose NAME.csv [--report DIR] [--json OUT.json]`` finds, names and adds
missing effects (progress on stderr, summary on stdout).
``make-dataset --rig joint-rig --hide joint_friction --out DIR`` writes a
hidden-effect truth dataset (NAME.csv + NAME.json, the answer in NAME.truth.json).
"""

from __future__ import annotations

import json
import sys

__all__ = ["register"]


def _diagnose(args) -> int:
    from awiwi_drake.discrepancy import DiagnosisInterrupted, diagnose, load_dataset
    from awiwi_drake.discrepancy.catalog import PARAM_UNITS
    from awiwi_drake.discrepancy.report import findings_text, json_summary, write_report
    from awiwi_drake.parameters.discrepancy import DiscrepancySettings

    from . import load_parameters, output_dir, output_file

    # every output path is checked before the (long) diagnosis starts
    report_dir = output_dir(args.report, "--report") if args.report else None
    json_path = output_file(args.json, "--json", suffixes=(".json",)) if args.json else None
    ds = load_dataset(args.dataset)
    settings = load_parameters(DiscrepancySettings(), args)
    progress = None if args.quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))

    def write_json(dx):
        if json_path is not None:  # atomic: an interruption never leaves a half-written file
            text = json.dumps(json_summary(dx), indent=1, default=float)
            tmp = json_path.with_name(json_path.name + ".part")
            tmp.write_text(text)
            tmp.replace(json_path)

    try:
        dx = diagnose(ds, settings=settings, progress=progress, checkpoint=write_json)
    except DiagnosisInterrupted as exc:
        dx = exc.diagnosis
        write_json(dx)
        if report_dir is not None:
            write_report(dx, report_dir, figures=False)
        print(f"{dx.dataset}: interrupted after {len(dx.steps)} accepted step(s); partial summary written"
              + (f" to {json_path}" if json_path else "") + (f" and {report_dir}" if report_dir else ""),
              file=sys.stderr)
        return 130
    write_json(dx)  # first the small file, so a failure leaves no report that looks complete
    if report_dir is not None:
        md = write_report(dx, report_dir)
        print(f"report: {md}", file=sys.stderr)
    if not hasattr(dx, "nrmse_before"):   # a finger diagnosis: effects with their tendon
        print(dx.text())
        print(findings_text(dx))
        return 0
    named = ", ".join(e + (f" on {dx.places[e]}" if e in dx.places else "") for e in dx.named_effects) or "none"
    print(f"{dx.dataset}: {dx.verdict}; named effects: {named}")
    if dx.nuisance_corrections:
        print(f"calibration corrections: {', '.join(dx.nuisance_corrections)}")
    for s in dx.steps:
        ps = ", ".join(f"{k} = {v:.4g} +- {s.uncertainties.get(k, float('nan')):.2g} {PARAM_UNITS.get(k, '?')}"
                       for k, v in s.parameters.items())
        print(f"  {s.effect} [{s.status}, confidence {s.confidence:.2f}]: {ps}")
        if s.status == "not separable":
            print(f"    not separable with these data from {', '.join(s.members[1:])}; "
                  f"to separate them: {s.experiment}")
    print(findings_text(dx))
    print(f"NRMSE {dx.nrmse_before:.4f} -> {dx.nrmse_after:.4f} "
          f"(fit {dx.fit_percent_before:.1f}% -> {dx.fit_percent_after:.1f}%)")
    return 0


def _snr(text: str) -> float | None:
    """argparse type of --snr: a finite number of dB, or inf/none for noise-free data."""
    from . import finite_float

    return None if text.strip().lower() in ("inf", "none") else finite_float(text)


def _seed(text: str) -> int:
    import argparse

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if not 0 <= value < 2 ** 32:
        raise argparse.ArgumentTypeError(f"{text!r} must be in [0, 2^32)")
    return value


def _names(values) -> list[str]:
    """The names of a repeatable, comma-separated option (``--hide a,b --hide c``)."""
    return [x.strip() for v in values or [] for x in v.split(",") if x.strip()]


def _make_dataset(args) -> int:
    from awiwi_drake.discrepancy import make_truth_dataset, save_dataset
    from awiwi_drake.discrepancy.data import is_finger_rig
    from awiwi_drake.parameters.discrepancy import TruthGeneratorParams

    from . import output_dir

    if args.name is not None and (args.name in ("", ".", "..") or "/" in args.name or "\\" in args.name
                                  or args.name != args.name.strip()):
        raise ValueError(f"--name {args.name!r}: a plain file stem is expected (no folders: the files go "
                         f"into --out)")
    out = output_dir(args.out)
    hidden = [x for x in _names(args.hide) if x != "none"]
    nuisance = _names(args.nuisance)
    gen = TruthGeneratorParams()
    if args.duration is not None:
        gen = gen.replace(duration=args.duration)
    rig = args.rig
    if is_finger_rig(rig):
        return _make_finger_dataset(args, out, hidden)
    if args.joint_angles:
        raise ValueError(f"--joint-angles: only for finger datasets (the {args.rig} records its link angle anyway)")
    if args.place is not None and args.place not in (1, 2):
        raise ValueError(f"--place {args.place}: the joint rig has tendons 1 and 2")
    from awiwi_drake.config import SimulationProgress

    with SimulationProgress("make-dataset", quiet=args.quiet) as progress:
        ds = make_truth_dataset(rig, hidden, snr_db=args.snr, seed=args.seed, nuisance=nuisance, gen=gen,
                                name=args.name, keep_clean=False, progress=progress, place=args.place)
    path = save_dataset(ds, out)
    snr = "inf" if args.snr is None else f"{args.snr:g}"
    print(f"{path} (+ .json; answer in {path.stem}.truth.json): rig {args.rig}, hidden {hidden or 'none'}, "
          f"SNR {snr} dB, seed {args.seed}" + (f", on tendon {args.place}" if args.place else ""))
    return 0


def _make_finger_dataset(args, out, hidden) -> int:
    from awiwi_drake.config import SimulationProgress
    from awiwi_drake.discrepancy import save_dataset
    from awiwi_drake.discrepancy.data import rig_finger
    from awiwi_drake.discrepancy.finger_truth import make_finger_dataset
    from awiwi_drake.parameters.discrepancy import FingerTruthParams

    if args.nuisance:
        raise ValueError(f"--nuisance: not available for {args.rig} (finger datasets hide physical effects only)")
    if len(hidden) > 1:
        raise ValueError(f"--hide {','.join(hidden)}: a finger dataset hides one effect at one place")
    if hidden and args.place is None:
        raise ValueError(f"--place: {args.rig} needs the tendon the hidden effect acts on (1-based)")
    gen = FingerTruthParams() if args.duration is None else FingerTruthParams(duration=args.duration)
    with SimulationProgress("make-dataset", quiet=args.quiet) as progress:
        ds = make_finger_dataset(rig_finger(args.rig), hidden, place=args.place, snr_db=args.snr,
                                 seed=args.seed, gen=gen, joint_angles=args.joint_angles, name=args.name,
                                 keep_clean=False, progress=progress)
    path = save_dataset(ds, out)
    snr = "inf" if args.snr is None else f"{args.snr:g}"
    tendon = ds.meta["truth"].get("tendon")
    print(f"{path} (+ .json; answer in {path.stem}.truth.json): rig {args.rig}, hidden {hidden or 'none'}"
          + (f" on tendon {args.place} ({tendon})" if hidden else "") + f", SNR {snr} dB, seed {args.seed}")
    return 0


def register(subparsers) -> None:
    from . import add_parameter_options, positive_float

    p = subparsers.add_parser(
        "diagnose", help="find, name and add missing effects in a dataset",
        description="Compare a measured dataset (NAME.csv + NAME.json) with the nominal model, localise the "
                    "disagreement, name the missing effects from the catalog, fit and add them (progress on "
                    "stderr, summary on stdout).")
    p.add_argument("dataset", help="NAME.csv (with NAME.json beside it)")
    p.add_argument("--report", metavar="DIR", help="write report.md, PNGs and summary.json into this folder")
    p.add_argument("--json", metavar="OUT.json", help="write the JSON summary to this file")
    add_parameter_options(p, what="DiscrepancySettings", example="e.g. 'window: 0.05'")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    p.set_defaults(func=_diagnose)

    m = subparsers.add_parser("make-dataset", help="generate a hidden-effect truth dataset")
    m.add_argument("--rig", choices=["tendon-rig", "joint-rig", "finger-index", "finger-middle", "finger-ring",
                                     "finger-fifth", "finger-thumb", "hand"], default="joint-rig",
                   help="the rig of the truth experiment (default joint-rig); finger-*: the package's finger "
                        "diagram at 1 kHz, effects motor_friction, guide_friction, motor_ripple, spring_hysteresis; "
                        "hand: the hand diagram (wrist still), the same effects on one of its 38 tendons")
    m.add_argument("--hide", action="append", metavar="EFFECT",
                   help="catalog effect hidden in the truth (repeat or comma-separate; 'none'): motor_friction, "
                        "motor_ripple, spring_hysteresis, joint_friction, guide_friction, delay, spring_drift, "
                        "backlash")
    m.add_argument("--place", type=int, default=None, metavar="TENDON",
                   help="joint-rig: the per-tendon hidden effects (motor_friction, guide_friction, "
                        "spring_hysteresis) act on tendon 1 or 2 only (default: both); finger-*: the tendon "
                        "(1-based, <finger>_h1...) the hidden effect acts on (required)")
    m.add_argument("--joint-angles", action="store_true",
                   help="finger-*: also record the joint angles (the hand has no joint sensors)")
    m.add_argument("--nuisance", action="append", metavar="NAME",
                   help="miscalibration in the truth: force_sensor, nominal_motor")
    m.add_argument("--snr", type=_snr, default=30.0, metavar="DB",
                   help="sensor SNR in dB, default 30 ('inf' for noise-free)")
    m.add_argument("--seed", type=_seed, default=0, help="random seed >= 0 of the truth draw and noise (default 0)")
    m.add_argument("--duration", type=positive_float, default=None, metavar="S",
                   help="recorded seconds (default 10)")
    m.add_argument("--name", default=None, help="file stem (default from rig/effects/SNR/seed)")
    m.add_argument("--quiet", action="store_true", help="no progress bar (it shows only on a terminal anyway)")
    req = m.add_argument_group("required options")
    req.add_argument("--out", required=True, metavar="DIR", help="output folder (created if missing)")
    m.set_defaults(func=_make_dataset)
