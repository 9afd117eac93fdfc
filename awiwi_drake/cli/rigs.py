"""CLI commands of the foundation: demo, export-diagrams, linearize, lqr, params."""

from __future__ import annotations

import argparse
import json

import numpy as np

from awiwi_drake.cli import CliError, add_parameter_options, load_parameters, output_dir, output_file

__all__ = ["register"]


def register(sub) -> None:
    from awiwi_drake.diagrams import TARGETS

    fmt = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser("demo", help="simulate joint-rig (pretension ramp + position step), write plots and diagrams",
                       formatter_class=fmt)
    p.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    add_parameter_options(p, what="the DemoScenario (pretension ramp f_start -> f_end over ramp_time, link_step at "
                                  "step_time, t_final)", example="e.g. 'link_step: 0.2'")
    p.set_defaults(func=_demo)

    p = sub.add_parser("export-diagrams", help="write the rig diagram graphs (.dot, and .svg/.png with Graphviz)")
    p.add_argument("--out", default="diagrams", help="output folder (default diagrams/)")
    p.set_defaults(func=_export)

    epilog = "targets:\n" + "\n".join(f"  {name}: {e['description']}" for name, e in TARGETS.items()) + (
        "\n\nParameters: --config FILE.yaml, then --set NAME=VALUE (field names as listed by"
        "\n'awiwi-drake params RIG'; nested sets are searched, dotted paths like motor.inertia also work).")
    rig_help = "target rig: " + ", ".join(TARGETS)
    p = sub.add_parser("linearize", help="print A, B and the poles at a rig's default operating point",
                       epilog=epilog, formatter_class=fmt)
    p.add_argument("rig", metavar="RIG", choices=list(TARGETS), help=rig_help)
    add_parameter_options(p)
    p.add_argument("--json", action="store_true",
                   help="print one JSON object {A, B, C, D, poles, damp, state_names, input_names, x0, u0, ...}")
    p.add_argument("--damp", action="store_true",
                   help="print the damping table: natural frequency, damping ratio, time constant per pole")
    p.add_argument("--bode", metavar="OUT.png", default=None,
                   help="write a Bode diagram (dB and phase on log axes, gain/phase margins) of --output / --input")
    p.add_argument("--output", default=None, metavar="NAME",
                   help="output channel of the Bode diagram, e.g. joint_angle, tendon_force, joint_angle[1] "
                        "(default: the rig's link/joint angle, or its tendon force)")
    p.add_argument("--input", default="motor_torque[0]", metavar="CHANNEL",
                   help="input channel of the Bode diagram (default motor_torque[0])")
    p.add_argument("--save", metavar="OUT.json", default=None,
                   help="save the linearisation (reload with LinearizationResult.load)")
    p.set_defaults(func=_linearize)

    p = sub.add_parser("lqr", help="LQR gain and closed-loop poles at a rig's default operating point",
                       epilog=epilog + "\n\n--q gives the diagonal of Q in the rig's state order.", formatter_class=fmt)
    p.add_argument("rig", metavar="RIG", choices=list(TARGETS), help=rig_help)
    req = p.add_argument_group("required options")
    req.add_argument("--q", required=True, help="comma-separated diagonal of Q (state order)")
    req.add_argument("--r", required=True, help="comma-separated diagonal of R (one per motor)")
    add_parameter_options(p)
    p.add_argument("--json", action="store_true", help="print one JSON object {K, S, Q, R, closed_loop_poles, ...}")
    p.add_argument("--save", metavar="OUT.json", default=None,
                   help="save the design with its linearisation (reload with LqrResult.load)")
    p.set_defaults(func=_lqr)

    p = sub.add_parser("params", help="list a rig's parameters with units, ranges and sources (or print them as YAML)",
                       epilog=epilog + "\n\n'params RIG --yaml > my.yaml' writes a file that --config reads back.",
                       formatter_class=fmt)
    p.add_argument("rig", metavar="RIG", choices=list(TARGETS), help=rig_help)
    add_parameter_options(p)
    p.add_argument("--yaml", action="store_true",
                   help="print the parameter set as YAML (Drake's yaml_dump_typed) instead of the table")
    p.set_defaults(func=_params)


def _floats(text: str, what: str) -> np.ndarray:
    try:
        vals = np.array([float(t) for t in text.split(",") if t.strip() != ""])
    except ValueError:
        raise CliError(f"{what}: cannot parse {text!r} as comma-separated numbers") from None
    if vals.size == 0 or not np.all(np.isfinite(vals)):
        raise CliError(f"{what}: expected finite comma-separated numbers, got {text!r}")
    return vals


def _params_of(args):
    from awiwi_drake.diagrams import TARGETS

    return load_parameters(TARGETS[args.rig]["params"](), args)


def _build(args) -> object:
    from awiwi_drake.diagrams import build_target

    return build_target(args.rig, params=_params_of(args))


def _default_bode_output(lin) -> str:
    for name in ("joint_angle", "tendon_force"):
        if name in lin.outputs:
            return lin.outputs[name].names[0]
    return lin.output_names[0]


def _linearize(args) -> int:
    from awiwi_drake.analysis import linearize, poles_table

    bode_path = None if args.bode is None else output_file(args.bode, "--bode", suffixes=(".png", ".pdf", ".svg"))
    save_path = None if args.save is None else output_file(args.save, "--save", suffixes=(".json",))
    rig = _build(args)
    outputs = ["state"] + [n for n in ("joint_angle", "tendon_force") if n in rig.output_names]
    res = linearize(rig, outputs=outputs)
    if save_path is not None:
        res.save(save_path)
    fr = None
    if bode_path is not None:
        import matplotlib
        matplotlib.use("Agg")
        fr = res.bode(input=args.input, output=args.output or _default_bode_output(res))
        fig, _ = fr.plot()
        fig.suptitle(f"{rig.name}: {fr.output_name} / {fr.input_name}")
        fig.tight_layout()
        fig.savefig(bode_path, dpi=120)
    if args.json:
        data = res.to_json()
        if fr is not None:
            data["bode"] = fr.to_json()
        print(json.dumps(data))
        return 0
    np.set_printoptions(precision=6, suppress=False, linewidth=140)
    print(f"{rig.name}: state = [{', '.join(rig.state_names)}], input = motor_torque")
    print("A =\n" + str(res.A))
    print("B =\n" + str(res.B))
    print("poles [1/s]:\n" + poles_table(res))
    if args.damp:
        print("damping:\n" + str(res.damp()))
    if fr is not None:
        m = fr.margins()
        print(f"Bode {fr.output_name} / {fr.input_name} written to {bode_path}: gain margin "
              f"{m['gain_margin_db']:.4g} dB at {m['phase_crossover']:.4g} rad/s, phase margin "
              f"{m['phase_margin']:.4g} deg at {m['gain_crossover']:.4g} rad/s (unity feedback)")
    if save_path is not None:
        print(f"linearisation saved to {save_path}")
    return 0


def _lqr(args) -> int:
    from awiwi_drake.analysis import lqr

    save_path = None if args.save is None else output_file(args.save, "--save", suffixes=(".json",))
    rig = _build(args)
    q = _floats(args.q, "--q")
    r = _floats(args.r, "--r")
    if q.size != rig.num_states:
        raise CliError(f"--q has {q.size} entries; {args.rig} has {rig.num_states} states "
                       f"({', '.join(rig.state_names)})")
    m = rig.diagram.GetInputPort("motor_torque").size()
    if r.size != m:
        raise CliError(f"--r has {r.size} entries; {args.rig} has {m} motor input(s)")
    res = lqr(rig, np.diag(q), np.diag(r))
    if save_path is not None:
        res.save(save_path)
    if args.json:
        print(json.dumps(res.to_json()))
        return 0
    np.set_printoptions(precision=6, linewidth=140)
    print(f"{rig.name}: state = [{', '.join(rig.state_names)}]")
    print("K =\n" + str(res.K))
    print("closed-loop damping:\n" + str(res.closed_loop.damp()))
    if save_path is not None:
        print(f"design saved to {save_path}")
    return 0


def _params(args) -> int:
    from awiwi_drake.parameters import provenance_table
    from awiwi_drake.parameters.yaml_io import to_yaml

    params = _params_of(args)
    print(to_yaml(params) if args.yaml else provenance_table(params), end="\n" if not args.yaml else "")
    return 0


def _export(args) -> int:
    from awiwi_drake.diagrams import export_all

    for line in export_all(output_dir(args.out)):
        print(line)
    return 0


def _demo(args) -> int:
    from awiwi_drake.export import export_diagram
    from awiwi_drake.reproductions.demo import run_demo

    from awiwi_drake.config import short_mode
    from awiwi_drake.parameters.rigs import DemoScenario

    out = output_dir(args.out)
    default = DemoScenario(t_final=1.0) if short_mode() else DemoScenario()
    scenario = load_parameters(default, args)
    report, graphs = run_demo(out, scenario=scenario)
    for stem, diagram in graphs.items():
        export_diagram(diagram, out, stem, max_depth=1, quiet=True)
    print(report)
    return 0
