"""Every bad input of issue 13 ends in one clear line naming the option/file/key/row, with a non-zero
exit (CLI, run in-process through ``main``) or a ``ValueError`` (library); valid variants are accepted.

Datasets are built from one plausible synthetic recording (a joint rig whose measured forces follow
the nominal spring at the measured elongation) and then broken in one way per case.
"""

from __future__ import annotations

import codecs
import json
import math
import pathlib

import numpy as np
import pytest

from awiwi_drake.cli import main
from awiwi_drake.discrepancy import Dataset, load_dataset, save_dataset

PARAMS = {"motor_inertia": 2e-3, "motor_damping": 1.2e-3, "motor_pulley_radius": 0.006,
          "spring_poly": [1.2e4, 2.5e6], "link_inertia": 1e-4, "link_damping": 1.2e-3, "link_pulley_radius": 0.008}


def _spring(x):
    return sum(c * x ** (k + 1) for k, c in enumerate(PARAMS["spring_poly"]))


def _dataset() -> Dataset:
    t = np.arange(400) * 1e-3
    w = np.sin(2 * np.pi * 5 * t)
    th1, th2, q = 0.3 + 0.05 * w, 0.3 - 0.05 * w, 0.1 * w
    rm, rq = PARAMS["motor_pulley_radius"], PARAMS["link_pulley_radius"]
    f1, f2 = _spring(rm * th1 - rq * q + 1e-3), _spring(rm * th2 + rq * q + 1e-3)
    ins = {"motor_torque_1": rm * f1, "motor_torque_2": rm * f2}
    outs = {"motor_angle_1": th1, "motor_angle_2": th2, "tendon_force_1": f1, "tendon_force_2": f2,
            "joint_angle": q}
    init = {"motor_angle_1": 0.3, "motor_velocity_1": 0.0, "motor_angle_2": 0.3, "motor_velocity_2": 0.0,
            "joint_angle": 0.0, "joint_velocity": 0.0}
    return Dataset("run", "joint-rig", t, ins, outs, dict(PARAMS), init)


@pytest.fixture
def good(tmp_path) -> pathlib.Path:
    return save_dataset(_dataset(), tmp_path / "data")


def _edit_json(path: pathlib.Path, fn) -> pathlib.Path:
    jp = path.with_suffix(".json")
    meta = json.loads(jp.read_text())
    fn(meta)
    jp.write_text(json.dumps(meta))
    return path


def _scale_column(path: pathlib.Path, column: str, factor: float) -> pathlib.Path:
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    j = header.index(column)
    out = [lines[0]]
    for line in lines[1:]:
        cells = line.split(",")
        cells[j] = repr(float(cells[j]) * factor)
        out.append(",".join(cells))
    path.write_text("\n".join(out) + "\n")
    return path


def _set_column(path: pathlib.Path, column: str, value: float) -> pathlib.Path:
    return _scale_column(path, column, 0.0) if value == 0 else _scale_column(path, column, 1.0)


def _zero_all(path: pathlib.Path) -> pathlib.Path:
    lines = path.read_text().splitlines()
    out = [lines[0]] + [",".join([ln.split(",")[0]] + ["0"] * (len(ln.split(",")) - 1)) for ln in lines[1:]]
    path.write_text("\n".join(out) + "\n")
    return path


def _rename(path: pathlib.Path, old: str, new: str, files=(".csv", ".json")) -> pathlib.Path:
    for f in (path.with_suffix(x) for x in files):
        f.write_text(f.read_text().replace(old, new))
    return path


# -------------------------------------------------------------------------------------------------------- datasets
DATASET_CASES = [
    # a dataset written with the earlier column names: refused naming the column and its one name, never aliased
    ("old-link-columns", lambda p: _rename(_rename(p, "joint_angle", "link_angle"), "joint_velocity", "link_velocity"),
     "run.json: 'link_angle' is now named 'joint_angle'"),
    ("old-link-column-in-csv", lambda p: _rename(p, "joint_angle", "link_angle", (".csv",)),
     "run.csv: 'link_angle' is now named 'joint_angle'"),
    ("old-link-velocity-key", lambda p: _rename(p, "joint_velocity", "link_velocity", (".json",)),
     "run.json: 'link_velocity' is now named 'joint_velocity'"),
    # (id, edit(path) -> path, message fragment)
    ("rig-list", lambda p: _edit_json(p, lambda m: m.update(rig=["joint"])), "'rig' must be a name"),
    ("spring-null", lambda p: _edit_json(p, lambda m: m["parameters"].update(spring_poly=[1.2e4, None])),
     "'spring_poly'[1] = None is not a number"),
    ("spring-string", lambda p: _edit_json(p, lambda m: m["parameters"].update(spring_poly=["1e4"])),
     "'spring_poly'[0] = '1e4' is not a number"),
    ("initial-list", lambda p: _edit_json(p, lambda m: m["initial_state"].update(joint_angle=[0.0])),
     "initial_state 'joint_angle' = [0.0] is not a number"),
    ("initial-string", lambda p: _edit_json(p, lambda m: m["initial_state"].update(joint_angle="0")),
     "initial_state 'joint_angle' = '0' is not a number"),
    ("inputs-int", lambda p: _edit_json(p, lambda m: m.update(inputs=3)), "'inputs' must be a list of names"),
    ("outputs-string", lambda p: _edit_json(p, lambda m: m.update(outputs="joint_angle")),
     "'outputs' must be a list of names"),
    ("bool-parameter", lambda p: _edit_json(p, lambda m: m["parameters"].update(motor_inertia=True)),
     "'motor_inertia' = True is not a number"),
    ("huge-inertia", lambda p: _edit_json(p, lambda m: m["parameters"].update(motor_inertia=1e30)),
     "'motor_inertia' = 1e+30 [kg m^2] is implausibly large"),
    ("10m-pulley", lambda p: _edit_json(p, lambda m: m["parameters"].update(motor_pulley_radius=10.0)),
     "'motor_pulley_radius' = 10 [m] is implausibly large"),
    ("forces-in-kN", lambda p: _scale_column(_scale_column(p, "tendon_force_1", 1e-3), "tendon_force_2", 1e-3),
     "column 'tendon_force_1' peaks at"),
    ("forces-x1000", lambda p: _scale_column(p, "tendon_force_2", 1e3), "forces must be in N"),
    ("force-x1e300", lambda p: _scale_column(p, "tendon_force_1", 1e300), "column 'tendon_force_1'"),
    ("torque-x1e300", lambda p: _scale_column(p, "motor_torque_1", 1e300), "column 'motor_torque_1' reaches"),
    ("link-degrees", lambda p: _scale_column(p, "joint_angle", 180 / math.pi), "degrees are 57x larger"),
    ("motor-degrees", lambda p: _scale_column(p, "motor_angle_1", 180 / math.pi),
     "column 'motor_angle_1' moves the tendon"),
    ("all-zero", _zero_all, "no excitation"),
    ("dead-sensor", lambda p: _scale_column(p, "joint_angle", 0.0), "column 'joint_angle' is constant"),
    ("csv-not-utf8", lambda p: (p.write_bytes(p.read_bytes().replace(b"time", b"t\xefme", 1)), p)[1],
     "run.csv: not UTF-8"),
    ("json-not-utf8", lambda p: (p.with_suffix(".json").write_bytes(b"\xff\xfe{}"), p)[1], "run.json: not UTF-8"),
    ("bad-cell", lambda p: (p.write_text(p.read_text().replace("\n", "\n0.5,x,", 1).replace("0.5,x,", "", 0)), p)[1],
     "row 2"),
]


@pytest.mark.parametrize("edit,message", [c[1:] for c in DATASET_CASES], ids=[c[0] for c in DATASET_CASES])
def test_bad_dataset_is_one_named_line(good, edit, message, capsys):
    path = edit(good)
    with pytest.raises(ValueError) as info:
        load_dataset(path)
    assert message in str(info.value), str(info.value)
    # the CLI: one line on stderr, exit 2, nothing written
    assert main(["diagnose", str(path), "--quiet", "--report", str(good.parent / "rep")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and message in err and "Traceback" not in err
    assert not (good.parent / "rep" / "report.md").exists()


def test_dataset_path_that_is_a_directory(good, capsys):
    assert main(["diagnose", str(good.parent), "--quiet"]) == 2
    assert "is a directory" in capsys.readouterr().err


def test_utf8_bom_and_crlf_are_accepted(good):
    ref = load_dataset(good)
    good.write_bytes(codecs.BOM_UTF8 + good.read_bytes().replace(b"\n", b"\r\n"))
    jp = good.with_suffix(".json")
    jp.write_bytes(codecs.BOM_UTF8 + jp.read_bytes())
    back = load_dataset(good)
    np.testing.assert_array_equal(back.outputs["joint_angle"], ref.outputs["joint_angle"])
    assert back.parameters == ref.parameters


def test_cli_rig_spelling_in_dataset_json(good):
    """One spelling per rig: the dataset, the written JSON and the messages use the package's rig name
    ('joint-rig'); a short name ('joint') is refused, naming the known ones."""
    assert json.loads(good.with_suffix(".json").read_text())["rig"] == "joint-rig"
    assert load_dataset(good).rig == "joint-rig"
    _edit_json(good, lambda m: m.update(rig="joint"))
    with pytest.raises(ValueError, match="unknown rig 'joint' .known: tendon-rig, joint-rig, finger-index"):
        load_dataset(good)
    _edit_json(good, lambda m: m.update(rig="joint-rig"))
    _edit_json(good, lambda m: m["parameters"].update(bogus=1.0))
    with pytest.raises(ValueError, match="unknown parameter 'bogus' for rig 'joint-rig'"):
        load_dataset(good)


def test_dataset_memory_is_a_few_times_the_file(tmp_path):
    """Loading needs the text plus one float array: peak Python allocation < 5x the file size."""
    import tracemalloc

    ds = _dataset()
    n = 40
    big = Dataset("big", "joint-rig", np.arange(400 * n) * 1e-3,
                  {k: np.tile(v, n) for k, v in ds.inputs.items()},
                  {k: np.tile(v, n) for k, v in ds.outputs.items()}, ds.parameters, ds.initial_state)
    path = save_dataset(big, tmp_path)
    size = path.stat().st_size
    tracemalloc.start()
    load_dataset(path)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert size > 1e6 and peak < 5 * size, f"peak {peak / 1e6:.1f} MB for a {size / 1e6:.1f} MB file"


# -------------------------------------------------------------------------------------------------------- CLI
def _file(tmp_path):
    f = tmp_path / "afile"
    f.write_text("x")
    return f


CLI_CASES = [
    # (id, argv builder(tmp_path, dataset) -> argv, exit status, message fragment)
    ("demo-out-file", lambda t, d: ["demo", "--out", str(_file(t))], 2, "exists and is not a directory"),
    ("demo-out-unwritable", lambda t, d: ["demo", "--out", str(_file(t) / "sub")], 2, "cannot create the folder"),
    ("export-out-file", lambda t, d: ["export-diagrams", "--out", str(_file(t))], 2, "--out"),
    ("compare-out-file", lambda t, d: ["compare", "--rig", "joint-rig", "--controllers", "pd", "--out",
                                       str(_file(t))], 2, "exists and is not a directory"),
    ("compare-delay-huge", lambda t, d: ["compare", "--rig", "joint-rig", "--controllers", "pd", "--out", str(t),
                                         "--delay", "1e6"], 2, "argument --delay"),
    ("compare-rate-huge", lambda t, d: ["compare", "--rig", "joint-rig", "--controllers", "pd", "--out", str(t),
                                        "--rate", "1e9"], 2, "argument --rate"),
    ("compare-rate-nan", lambda t, d: ["compare", "--rig", "joint-rig", "--controllers", "pd", "--out", str(t),
                                       "--rate", "nan"], 2, "argument --rate"),
    ("compare-saturation", lambda t, d: ["compare", "--rig", "joint-rig", "--controllers", "pd", "--out", str(t),
                                         "--saturation", "-3"], 2, "argument --saturation"),
    ("compare-bad-rig", lambda t, d: ["compare", "--rig", "joint_rig", "--list"], 2, "argument --rig"),
    ("compare-load-negative", lambda t, d: ["compare", "--rig", "joint-rig", "--controllers", "pd", "--out", str(t),
                                            "--load", "-0.1"], 2, "argument --load"),
    ("compare-load-huge", lambda t, d: ["compare", "--rig", "joint-rig", "--controllers", "pd", "--out", str(t),
                                        "--load", "1e6"], 2, "--load: CompareTestParams.disturbance_torque"),
    ("compare-load-tendon", lambda t, d: ["compare", "--rig", "tendon-rig", "--controllers", "tendon-pd", "--out",
                                          str(t), "--load", "0.1"], 2, "--load: the tendon rig"),
    ("animate-out-dir", lambda t, d: ["animate", "--out", str(t)], 2, "--out"),
    ("animate-out-dir-html", lambda t, d: ["animate", "--out", str((t / "x.html").mkdir() or t / "x.html")], 2,
     "is a directory"),
    ("animate-duration-inf", lambda t, d: ["animate", "--duration", "inf"], 2, "argument --duration"),
    ("animate-duration-neg", lambda t, d: ["animate", "--duration", "-1"], 2, "argument --duration"),
    ("animate-finger-short-name", lambda t, d: ["animate", "--target", "index", "--out", str(t / "x.html")], 2,
     "target = 'index': not a hand rig (one of hand, finger-thumb, finger-index"),
    ("make-dataset-snr-word", lambda t, d: ["make-dataset", "--snr", "loud", "--out", str(t)], 2, "argument --snr"),
    ("make-dataset-snr-nan", lambda t, d: ["make-dataset", "--snr", "nan", "--out", str(t)], 2, "argument --snr"),
    ("make-dataset-seed-neg", lambda t, d: ["make-dataset", "--seed", "-1", "--out", str(t)], 2, "argument --seed"),
    ("make-dataset-old-rig-name", lambda t, d: ["make-dataset", "--rig", "joint", "--out", str(t)], 2,
     "argument --rig"),
    ("make-dataset-out-file", lambda t, d: ["make-dataset", "--out", str(_file(t))], 2, "--out"),
    ("make-dataset-no-out", lambda t, d: ["make-dataset"], 2, "--out"),
    ("make-dataset-name-escapes-out", lambda t, d: ["make-dataset", "--name", "../evil", "--out", str(t)], 2,
     "--name '../evil': a plain file stem"),
    ("make-dataset-name-folder", lambda t, d: ["make-dataset", "--name", "a/b", "--out", str(t)], 2,
     "--name 'a/b': a plain file stem"),
    ("make-dataset-place-3", lambda t, d: ["make-dataset", "--place", "3", "--out", str(t)], 2,
     "--place 3: the joint rig has tendons 1 and 2"),
    ("make-dataset-place-nothing-hidden", lambda t, d: ["make-dataset", "--place", "1", "--out", str(t)], 2,
     "--place 1: only a hidden per-tendon effect"),
    ("make-dataset-place-unplaced-effect", lambda t, d: ["make-dataset", "--hide", "motor_ripple", "--place", "2",
                                                         "--out", str(t)], 2, "hidden: motor_ripple"),
    ("make-dataset-finger-place-nothing-hidden", lambda t, d: ["make-dataset", "--rig", "finger-index", "--place", "2",
                                                               "--out", str(t)], 2, "--place 2: nothing hidden"),
    ("make-dataset-joint-angles-on-rig", lambda t, d: ["make-dataset", "--joint-angles", "--out", str(t)], 2,
     "--joint-angles: only for finger datasets"),
    ("make-dataset-finger-nuisance", lambda t, d: ["make-dataset", "--rig", "finger-index", "--nuisance",
                                                   "force_sensor", "--out", str(t)], 2, "--nuisance: not available"),
    ("make-dataset-finger-two-effects", lambda t, d: ["make-dataset", "--rig", "finger-index", "--hide",
                                                      "motor_friction,guide_friction", "--place", "1", "--out", str(t)],
     2, "one effect at one place"),
    ("compare-tests-empty", lambda t, d: ["compare", "--rig", "joint-rig", "--controllers", "pd", "--out", str(t),
                                          "--tests", ""], 2, "--tests: give at least one name"),
    ("compare-set-unknown", lambda t, d: ["compare", "--rig", "finger-index", "--controllers", "backstepping", "--out",
                                          str(t), "--set", "no_such=1"], 2, "unknown parameter 'no_such'"),
    ("diagnose-report-file", lambda t, d: ["diagnose", str(d), "--report", str(_file(t))], 2, "--report"),
    ("diagnose-json-dir", lambda t, d: ["diagnose", str(d), "--json", str(t)], 2, "--json"),
    ("diagnose-json-unwritable", lambda t, d: ["diagnose", str(d), "--json", str(_file(t) / "x.json")], 2,
     "--json"),
    ("diagnose-missing", lambda t, d: ["diagnose", str(t / "nope.csv")], 2, "nope.csv: no such file"),
    ("params-bad-rig", lambda t, d: ["params", "joint_rig"], 2, "argument RIG: invalid choice: 'joint_rig'"),
    ("params-set-bool-as-number", lambda t, d: ["params", "joint-rig", "--set", "pretension=true"], 2,
     "JointRigParams.pretension: cannot parse 'true'"),
    ("params-set-huge", lambda t, d: ["params", "joint-rig", "--set", "motor.inertia=1e30"], 2,
     "MotorParams.inertia = 1e+30 is implausible"),
    ("linearize-config-missing", lambda t, d: ["linearize", "joint-rig", "--config", str(t / "no.yaml")], 2,
     "no.yaml: no such file"),
    ("linearize-config-unknown-key", lambda t, d: ["linearize", "joint-rig", "--config",
                                                   str((t / "c.yaml").write_text("nope: 1") and t / "c.yaml")], 2,
     "c.yaml: unknown key 'nope'"),
    ("linearize-config-bad-value", lambda t, d: ["linearize", "joint-rig", "--config",
                                                 str((t / "c.yaml").write_text("pretension: -5") and t / "c.yaml")],
     2, "JointRigParams.pretension = -5.0 is out of range"),
    ("demo-config-bad-value", lambda t, d: ["demo", "--out", str(t), "--config",
                                            str((t / "s.yaml").write_text("link_step: 9") and t / "s.yaml")], 2,
     "DemoScenario.link_step = 9.0 is out of range"),
    ("demo-set-unknown", lambda t, d: ["demo", "--out", str(t), "--set", "nope=1"], 2,
     "unknown parameter 'nope' for DemoScenario"),
    ("lqr-missing-q", lambda t, d: ["lqr", "joint-rig", "--r", "1,1"], 2, "--q"),
    ("unknown-command", lambda t, d: ["simulate-everything"], 2, "invalid choice"),
]


@pytest.mark.parametrize("argv,status,message", [c[1:] for c in CLI_CASES], ids=[c[0] for c in CLI_CASES])
def test_bad_cli_input_is_one_named_line(tmp_path, good, argv, status, message, capsys):
    work = tmp_path / "work"
    work.mkdir()
    assert main(argv(work, good)) == status
    err = capsys.readouterr().err
    assert message in err, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err


def test_failed_json_path_leaves_no_report(tmp_path, good, capsys):
    """--json is checked before the diagnosis: no report.md/summary.json that looks like a success."""
    rep = tmp_path / "rep"
    assert main(["diagnose", str(good), "--quiet", "--report", str(rep), "--json", str(tmp_path)]) == 2
    assert not (rep / "report.md").exists() and not (rep / "summary.json").exists()


def test_version_and_help_exit_zero(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.startswith("awiwi-drake ")
    assert main(["params", "--help"]) == 0
    assert "--set" in capsys.readouterr().out


# -------------------------------------------------------------------------------------------------------- library
def test_library_rejects_nonsense_with_value_errors():
    from awiwi_drake.parameters import FingerRigParams, JointRigParams, MotorParams, TendonGuideParams
    from awiwi_drake.parameters.components import JointFrictionParams
    from awiwi_drake.rigs import joint_rig

    cases = [
        (lambda: JointRigParams(motor=5), "JointRigParams.motor = 5 must be a MotorParams"),
        (lambda: MotorParams(inertia=True), "MotorParams.inertia = True is not a number"),
        (lambda: MotorParams(inertia=1e30), "MotorParams.inertia = 1e+30 is implausible"),
        (lambda: JointRigParams().with_overrides(["pretension=3"]), "expected a mapping"),
        (lambda: joint_rig().operating_point(joint_angle=float("nan")), "joint_angle = nan must be finite"),
        # a key the rig does not have (the link rigs call it joint_angle): named with the known keys,
        # not a TypeError from the rig's internal equilibrium function
        (lambda: joint_rig().operating_point(link_angle=0.1),
         "joint-rig.operating_point: unknown key 'link_angle'; known: pretension, joint_angle, external_torque"),
        # a per-name override given twice would silently keep one entry: refused, naming the field and the name
        (lambda: FingerRigParams().replace(tendon_guides=(("index_h2", TendonGuideParams()),) * 2),
         "FingerRigParams.tendon_guides: 'index_h2' is given twice"),
        (lambda: FingerRigParams().replace(joint_frictions=(("q21", JointFrictionParams()),) * 2),
         "FingerRigParams.joint_frictions: 'q21' is given twice"),
    ]
    for fn, message in cases:
        with pytest.raises(ValueError, match=message.replace("(", r"\(").replace("+", r"\+")):
            fn()


def test_a_non_finite_initial_state_is_one_named_line():
    """A NaN in the state a closed loop starts from is refused, naming the entry, in the sampled rig (whose
    discrete state is in integration coordinates) and the continuous one alike."""
    from awiwi_drake.control import closed_loop, make_controller
    from awiwi_drake.rigs import joint_rig
    rig = joint_rig()
    op = rig.operating_point(pretension=30.0)
    for sampled in (True, False):
        loop = closed_loop(rig, make_controller("pd", rig), rate_hz=3000.0, sampled_rig=sampled)
        x = np.array(op.state, float)
        x[2] = np.nan
        with pytest.raises(ValueError) as info:
            loop.create_context(op, state=x)
        message = str(info.value)
        assert message.startswith(f"closed_loop: state[2] ({rig.state_names[2]}) = nan must be finite"), message
        assert "\n" not in message


def _finger_stage_controller(**kw):
    from awiwi_drake.control.joint_design import joint_stage_controller
    from awiwi_drake.hand.diagrams import finger_diagram
    return joint_stage_controller(finger_diagram(finger="index"), "lqr", **kw)


# (id, options of joint_stage_controller on the index, exception, message): one line naming the option
STAGE_CASES = [
    ("observer-string", {"friction_observer": "yes"}, TypeError,
     "TendonChainController: friction_observer = 'yes' must be None or a FrictionObserverParams"),
    ("correction-number", {"stiffness_correction": 3}, TypeError,
     "joint_stage_controller: stiffness_correction = 3 must be None or a StiffnessCorrectionParams"),
    ("rate-negative", {"rate_hz": -5}, ValueError, r"joint_stage_controller: rate_hz = -5 must be a finite number > 0"),
    ("rate-zero", {"rate_hz": 0.0}, ValueError, r"joint_stage_controller: rate_hz = 0.0 must be a finite number > 0"),
    ("rate-string", {"rate_hz": "3k"}, ValueError, r"joint_stage_controller: rate_hz = '3k' must be a finite number"),
]


@pytest.mark.parametrize("options,error,message", [c[1:] for c in STAGE_CASES], ids=[c[0] for c in STAGE_CASES])
def test_bad_chain_options_are_one_named_line(options, error, message):
    with pytest.raises(error) as info:
        _finger_stage_controller(**options)
    assert str(info.value).startswith(message) and "\n" not in str(info.value), str(info.value)


def test_simulate_start_after_end_raises_not_exits():
    from awiwi_drake.analysis import simulate
    from awiwi_drake.rigs import flexible_joint_rig

    rig = flexible_joint_rig()
    with pytest.raises(ValueError, match="must be after the start time"):
        simulate(rig.diagram, rig.context(), 0.1, t_start=0.5)


def test_every_option_has_help_and_no_raw_rst():
    """CLI: every option and positional of every command has help text; no RST markup in help."""
    import argparse

    from awiwi_drake.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    missing = []
    for name, p in sub.choices.items():
        text = p.format_help()
        assert "``" not in text and ":func:" not in text and ":class:" not in text, f"{name}: raw RST in help"
        for a in p._actions:
            if isinstance(a, argparse._HelpAction):
                continue
            if not (a.help or "").strip():
                missing.append(f"{name} {'/'.join(a.option_strings) or a.dest}")
        for a in p._actions:  # required options are listed under a "required" heading
            if a.required and a.option_strings:
                group = next(g for g in p._action_groups if a in g._group_actions)
                assert "required" in (group.title or ""), f"{name} {a.option_strings[0]} required but not shown so"
    assert not missing, "options without help: " + ", ".join(missing)


def test_bad_rates_of_the_chain_and_the_loop_are_one_named_line():
    from awiwi_drake.control import closed_loop, make_controller
    from awiwi_drake.control.chain import TendonChainController
    from awiwi_drake.control.joint_design import design_joint_stage
    from awiwi_drake.hand.diagrams import finger_diagram
    rig = finger_diagram(finger="index")
    law = design_joint_stage(rig, "cascaded").law
    with pytest.raises(ValueError, match=r"^TendonChainController: rate_hz = 0 must be a finite number > 0 \[Hz\]$"):
        TendonChainController(rig, law, rate_hz=0)
    with pytest.raises(ValueError, match=r"^closed_loop \(None: continuous\): rate_hz = '3k' must be a finite number"):
        closed_loop(rig, make_controller("joint-pd", rig), rate_hz="3k")
