"""awiwi-drake compare: run the standard closed-loop tests on registered controllers.

Writes metrics.csv (one row per controller, test and joint), metrics.md and plots
(step.png, sine.png, disturbance.png, sweep_gain.png; on a finger or the hand one
figure per finger and test, e.g. step_index.png) into --out.  On fingers and the
hand every joint (independent DoF) is tested at once: step, sine and an
external-torque step on the k-th joint of every finger.  Unknown
controller names or controllers that do not fit the rig exit with status 2
and a one-line error.  Every (controller, test, joint) row is independent: a
finished run that saturates or goes slack has status "flagged"; a simulation
stopped by a physical failure has the cause as status ("diverged",
"infeasible_force", ...), the time in "failed_at", NaN metrics and one line on
stderr, the other rows and plots are still written, and the exit status is 1.
"""

from __future__ import annotations

import argparse

from awiwi_drake.cli import add_parameter_options, limited_float, load_parameters, output_dir, positive_float

__all__ = ["register", "run"]

FINGER_RIGS = ("finger-thumb", "finger-index", "finger-middle", "finger-ring", "finger-fifth", "hand")


def register(subparsers) -> None:
    from awiwi_drake.diagrams import TARGETS

    p = subparsers.add_parser("compare", help="compare controllers on a rig (step, sine, disturbance, sweep)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    req = p.add_argument_group("required options (except with --list)")
    req.add_argument("--rig", required=True, choices=sorted(TARGETS), help="rig to control")
    req.add_argument("--controllers", help="comma-separated registered names, e.g. pd,lqr (see --list); "
                     "NAME:no-observer: a chain controller without its default ch. 9 friction observer")
    req.add_argument("--out", metavar="DIR", help="output folder (created if missing)")
    p.add_argument("--list", action="store_true", help="list the controllers that fit --rig and exit")
    p.add_argument("--tests", default=None, help="comma-separated subset of step,sine,disturbance,sweep")
    p.add_argument("--rate", type=limited_float("max_rate", "Hz", low="min_rate", zero=True), metavar="HZ",
                   help="control rate [Hz] (default: the controller's, 3000); 0 = continuous")
    p.add_argument("--delay", type=limited_float("max_delay", "s"), metavar="S", help="round-trip delay [s], e.g. 333e-6")
    p.add_argument("--saturation", type=positive_float, default=None, metavar="NM", help="torque limit [Nm]")
    p.add_argument("--load", type=positive_float, default=None, metavar="NM",
                   help="external-torque step of the load test on every joint [Nm] (default: fingers/hand sized per "
                        "joint above its friction observer's bound, control.compare.size_loads; link rigs 0.02)")
    p.add_argument("--short", action="store_true", help="shorter runs (as AWIWI_SHORT=1)")
    p.add_argument("--quiet", action="store_true", help="no progress bar (it shows only on a terminal anyway)")
    add_parameter_options(p, "the rig's parameter set", "e.g. --set guide_friction=false for a finger without the "
                          "guides' friction")
    p.add_argument("--controller-set", action="append", default=[], metavar="NAME=VALUE",
                   help="fingers and the hand: override one field of the controllers' parameters "
                        "(CompareControllerParams: their HandChainParams, e.g. distribution_method=algorithm2, for the "
                        "chain and backstepping controllers; stiffness_correction=true and epsilon=... for ch. 8's "
                        "correction of the chain designs); repeatable")
    p.add_argument("--sensors", choices=("estimated", "ideal"), default=None,
                   help="fingers and the hand: joint angles from the tendon-length estimator (5.15) (default) or "
                        "the plant's true joint state (an ideal-sensor comparison)")
    p.set_defaults(func=run)


def _parse_list(text: str, what: str) -> list[str]:
    items = [t.strip() for t in text.split(",") if t.strip()]
    if not items:
        raise ValueError(f"--{what}: give at least one name")
    if len(set(items)) != len(items):
        raise ValueError(f"--{what}: duplicate names in {text!r}")
    return items


def run(args) -> int:
    import math
    import sys

    from awiwi_drake.config import short_mode
    from awiwi_drake.control.compare import (TESTS, build_loops, compare, compare_test_params, default_tests,
                                             design_step_duration, plot_gain_diagram, plot_joint_runs, plot_runs,
                                             short_test_params)
    from awiwi_drake.control.registry import controller_names, get_entry

    if args.list:
        for n in controller_names(args.rig):
            print(f"{n:16s} {get_entry(n, args.rig).description}")
        return 0
    if not args.controllers or not args.out:
        raise ValueError("give --controllers and --out (or --list)")
    out = output_dir(args.out)
    names = _parse_list(args.controllers, "controllers")
    for n in names:  # validate every name before any simulation
        get_entry(n, args.rig)
    tests = _parse_list(args.tests, "tests") if args.tests is not None else None
    for t in tests or []:
        if t not in TESTS:
            raise ValueError(f"--tests: unknown test {t!r}; known: {', '.join(TESTS)}")
    if tests is not None and "disturbance" in tests and args.rig == "tendon-rig":
        raise ValueError("--tests: 'disturbance' needs an external torque input; the tendon rig has none")
    if args.load is not None and args.rig == "tendon-rig":
        raise ValueError("--load: the tendon rig has no external torque input (no load test)")
    load = {} if args.load is None else dict(disturbance_torque=args.load, load_bound_factor=0.0)   # not sized
    try:
        compare_test_params(args.rig, **load)        # checked before anything is built
    except ValueError as exc:
        raise ValueError(f"--load: {exc}") from None
    from awiwi_drake.diagrams import TARGETS, build_target
    rig_params = load_parameters(TARGETS[args.rig]["params"](), args)     # --config then --set
    for flag, given in (("--controller-set", args.controller_set), ("--sensors", args.sensors)):
        if given and args.rig not in FINGER_RIGS:
            raise ValueError(f"{flag}: only for fingers and the hand, not rig {args.rig!r}")
    from awiwi_drake.control.compare import factory_options
    from awiwi_drake.parameters.cli import CompareControllerParams
    ctrl_opts = load_parameters(CompareControllerParams(), args, option="controller_set").factory_options()
    try:
        factory_options(names, args.rig, ctrl_opts)
    except ValueError as exc:
        raise ValueError(f"--controller-set: {exc}") from None
    # the hand's wrist held at neutral: without the wrist input (its tendon offsets are then zero), which is faster
    kw = {"wrist": False} if args.rig == "hand" else {}

    def make_rig():
        return build_target(args.rig, params=rig_params, **kw)

    opts = {}
    if args.rate is not None:
        opts["rate_hz"] = None if args.rate == 0 else args.rate
    if args.delay is not None:
        opts["delay"] = args.delay
    if args.saturation is not None:
        opts["saturation"] = args.saturation
    if args.sensors == "ideal":
        opts["sensors"] = "ideal"
    loops = build_loops(make_rig, names, ctrl_opts, **opts)      # each controller designed once
    params = compare_test_params(args.rig, **load)
    if args.short or short_mode():
        params = short_test_params(make_rig, loops, params)
    else:       # the chosen window, or longer where the compared designs need it
        window = design_step_duration(make_rig, loops, params)
        if window is not None and window > params.step_duration:
            params = params.replace(step_duration=window)
    from awiwi_drake.config import progress_bar

    n_tests = len(tests if tests is not None else default_tests(next(iter(loops.values()))))
    with progress_bar(total=len(names) * n_tests, desc="compare", unit="test", quiet=args.quiet) as bar:
        def advance(label: str) -> None:
            bar.set_postfix_str(label, refresh=False)
            bar.update(1)

        result = compare(loops, tests=tests, params=params, progress=advance)
    result.table.to_csv(out / "metrics.csv")
    ref_unit = "N" if args.rig == "tendon-rig" else "rad"
    failed, n = result.table.failed(), len(result.table.rows)
    summary = (f"**{len(failed)} of {n} rows FAILED**: their simulation stopped (status = the cause, failed_at = "
               f"when; metrics NaN).\n\n" if failed else "")
    setup = "".join(f"- {k}: {v}\n" for k, v in (("controller parameters (--controller-set)",
                                                   ", ".join(args.controller_set)),
                                                  ("joint sensors (--sensors)", args.sensors)) if v)
    (out / "metrics.md").write_text(f"# Controller comparison on {args.rig}\n\n{setup and setup + chr(10)}{summary}"
                                    + result.table.to_markdown(ref_unit=ref_unit))
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    ylabel = "tendon force [N]" if args.rig == "tendon-rig" else "link angle [rad]"
    for test in dict.fromkeys(r.test for r in result.runs):
        if args.rig in FINGER_RIGS:
            fingers = dict.fromkeys(next(r for r in result.runs if r.test == test).meta["fingers"])
            for finger in fingers:
                fig, _ = plot_joint_runs(result, test, finger)
                fig.savefig(out / f"{test}_{finger}.png", dpi=110)
                plt.close(fig)
            continue
        if test == "sweep":
            fig, _ = plot_gain_diagram(result, unit=ref_unit)
            fig.savefig(out / "sweep_gain.png", dpi=110)
        else:
            fig, _ = plot_runs(result, test, ylabel=ylabel)
            fig.savefig(out / f"{test}.png", dpi=110)
        plt.close(fig)
    for r in failed:
        at = f" at t = {r.failed_at:.4g} s" if math.isfinite(r.failed_at) else ""
        print(f"compare: {r.controller} / {r.test} / {r.joint}: {r.status}{at}: {r.flags}", file=sys.stderr)
    print(f"wrote {out / 'metrics.csv'}, {out / 'metrics.md'} and plots; "
          + (f"{len(failed)} of {n} rows FAILED (status in metrics.csv)" if failed else f"all {n} rows ran"))
    return 1 if failed else 0
