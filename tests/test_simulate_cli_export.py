"""Monitors (divergence, slack, saturation), CLI contract, diagram export, parameter provenance."""

import dataclasses
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pydrake.systems.primitives import AffineSystem

from awiwi_drake.analysis import SimulationDivergedError, linearize, rig_monitors, simulate
from awiwi_drake.cli import main
from awiwi_drake.export import export_diagram
from awiwi_drake.parameters import (
    FlexibleJointParams, JointRigParams, MotorParams, Parameters, TendonRigParams, provenance_table)
from awiwi_drake.rigs import flexible_joint_rig, joint_rig, tendon_rig


def test_divergence_is_detected_and_named():
    unstable = AffineSystem(A=np.array([[200.0]]), B=np.zeros((1, 1)), f0=np.zeros(1), C=np.eye(1),
                            D=np.zeros((1, 1)), y0=np.zeros(1))
    ctx = unstable.CreateDefaultContext()
    ctx.SetContinuousState([1.0])
    unstable.get_input_port().FixValue(ctx, [0.0])
    with pytest.raises(SimulationDivergedError, match=r"diverged at t = .* state\[0\]"):
        simulate(unstable, ctx, 1.0, log=(), max_step=1e-3)


def test_tendon_slack_is_reported_with_its_interval():
    rig = tendon_rig()
    op = rig.operating_point(tendon_force=10.0)
    ctx = rig.context(op)
    rig.diagram.GetInputPort("motor_torque").FixValue(ctx, [-1.5])  # unwind: the tendon goes slack
    res = simulate(rig.diagram, ctx, 0.1, log=("tendon_force",), monitors=rig_monitors(rig))
    slack = res.events_of("tendon_slack")
    assert len(slack) == 1 and slack[0].channel == "tendon_force[0]"
    i = np.searchsorted(res.t, slack[0].t_start)
    assert res["tendon_force"][i, 0] <= 0.0 and res["tendon_force"][i - 1, 0] > 0.0
    with pytest.raises(RuntimeError, match="tendon_slack on tendon_force\\[0\\]"):
        ctx = rig.context(op)
        rig.diagram.GetInputPort("motor_torque").FixValue(ctx, [-1.5])
        simulate(rig.diagram, ctx, 0.1, log=(), monitors=rig_monitors(rig, raise_on_slack=True))


def test_actuator_saturation_is_reported_and_the_applied_torque_is_clipped():
    rig = joint_rig(params=JointRigParams(motor=MotorParams(torque_limit=0.5)))
    op = rig.operating_point()
    ctx = rig.context(op)
    rig.diagram.GetInputPort("motor_torque").FixValue(ctx, [2.0, op.motor_torque[1]])
    res = simulate(rig.diagram, ctx, 0.01, log=("applied_torque",), monitors=rig_monitors(rig))
    sat = res.events_of("actuator_saturation")
    assert [e.channel for e in sat] == ["motor_torque[0]"] and sat[0].extreme == 2.0
    assert np.max(res["applied_torque"][:, 0]) == pytest.approx(0.5)


def run_cli(*args):
    proc = subprocess.run([sys.executable, "-m", "awiwi_drake", *args], capture_output=True, text=True, timeout=300)
    return proc.returncode, proc.stdout, proc.stderr


def test_cli_linearize_json_matches_the_framework():
    code, out, err = run_cli("linearize", "flexible-joint", "--set", "link_inertia=7.2e-7", "--json")
    assert code == 0, err
    data = json.loads(out)
    ref = linearize(flexible_joint_rig(params=FlexibleJointParams(link_inertia=7.2e-7)))
    np.testing.assert_allclose(data["A"], ref.A)
    np.testing.assert_allclose(data["B"], ref.B)
    np.testing.assert_allclose([complex(*p) for p in data["poles"]], ref.poles)
    assert data["A"][1][0] == pytest.approx(-0.605 / 7.2e-7)


def test_cli_lqr_json_gain_and_poles(capsys):
    assert main(["lqr", "flexible-joint", "--q", "10,0.01,1,0.01", "--r", "0.01", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    K = np.array(data["K"])
    assert K.shape == (1, 4)
    A = linearize(flexible_joint_rig()).A
    B = np.array([[0], [0], [0], [500.0]])
    cl = np.sort_complex(np.linalg.eigvals(A - B @ K))
    np.testing.assert_allclose(np.sort_complex([complex(*p) for p in data["closed_loop_poles"]]), cl, rtol=1e-8)


@pytest.mark.parametrize("args, message", [
    (["linearize", "nope"], "argument RIG: invalid choice: 'nope'"),
    (["linearize", "joint-rig", "--set", "bogus=1"], "unknown parameter 'bogus'"),
    (["linearize", "joint-rig", "--set", "link_inertia=abc"], "cannot parse 'abc'"),
    (["linearize", "joint-rig", "--set", "link_inertia"], "NAME=VALUE"),
    (["lqr", "joint-rig", "--q", "1,2", "--r", "1"], "--q has 2 entries"),
    (["lqr", "flexible-joint", "--q", "1,x,1,1", "--r", "1"], "--q: cannot parse"),
])
def test_cli_errors_are_one_line_without_traceback(args, message, capsys):
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_cli_error_through_the_console_entry_point():
    code, out, err = run_cli("linearize", "tendon-rig", "--set", "inertia=-1")
    assert code == 2 and "MotorParams.inertia = -1.0 is out of range" in err and "Traceback" not in err


def test_export_writes_dot_and_images_or_says_why(tmp_path, monkeypatch, capsys):
    res = export_diagram(joint_rig().diagram, tmp_path, "jr", max_depth=1)
    text = res.dot.read_text()
    assert "digraph" in text and "motor_torque" in text and "rig_dynamics" in text
    monkeypatch.setattr("awiwi_drake.export.graphviz_available", lambda: False)
    res = export_diagram(joint_rig().diagram, tmp_path, "jr2")
    assert res.images == [] and res.skipped == ["jr2.svg", "jr2.png"]
    assert "Graphviz 'dot' not found" in capsys.readouterr().err


def test_committed_diagrams_are_current(tmp_path):
    # diagrams/ holds the output of `awiwi-drake export-diagrams`; regenerate and compare the .dot text.
    import pathlib
    from awiwi_drake.diagrams import DIAGRAM_EXPORTS, export_all
    export_all(tmp_path)
    committed = pathlib.Path(__file__).parent.parent / "diagrams"
    for stem, _, _ in DIAGRAM_EXPORTS:
        assert (committed / f"{stem}.dot").read_text() == (tmp_path / f"{stem}.dot").read_text(), \
            f"diagrams/{stem}.dot is stale: run `awiwi-drake export-diagrams`"


def _all_parameter_classes():
    """Every ``Parameters`` subclass defined anywhere in the package (all modules imported)."""
    import importlib
    import pkgutil
    import awiwi_drake
    for mod in pkgutil.walk_packages(awiwi_drake.__path__, "awiwi_drake."):
        if not mod.name.endswith("__main__"):
            importlib.import_module(mod.name)

    def subclasses(cls):
        return [c for s in cls.__subclasses__() for c in (s, *subclasses(s))]
    return sorted({c for c in subclasses(Parameters) if c.__module__.startswith("awiwi_drake.")},
                  key=lambda c: (c.__module__, c.__name__))


# A thesis citation: a table, figure, equation number, section, chapter or algorithm.
_THESIS_CITATION = re.compile(
    r"\btables?\s*\d+\.\d+|\bfig(ure)?s?\.?\s*\d+\.\d+|\(\d+\.\d+[a-z]?\)|\bsections?\s+\d+(\.\d+)*"
    r"|\bch(apter|\.)\s*\d+|\balgorithm\s+\d+", re.IGNORECASE)
# Or a choice with its reason: "chosen: <why>" (at least two words of reason).
_CHOSEN = re.compile(r"^chosen:\s*\S+\s+\S+", re.IGNORECASE)
_FILE = re.compile(r"\b[\w./-]+\.(?:md|py|txt|csv|json|yaml|yml|ipynb|npz)\b", re.IGNORECASE)
# The project's chapter map outside the repository (with or without its extension): sources cite the thesis itself.
_NOTES = re.compile(r"\bMODEL_NOTES\b")


def test_every_parameter_has_unit_source_and_valid_default():
    """Each field of each parameter class has a unit and a source that cites the thesis (table, figure,
    equation, section, chapter, algorithm) or says ``chosen: why``; a cited file exists in the repository."""
    repo = Path(__file__).resolve().parents[1]
    tracked = {p.name for p in repo.rglob("*") if ".git" not in p.parts}
    classes = _all_parameter_classes()
    assert len(classes) >= 40
    bad = []
    for cls in classes:
        inst = cls()
        for name, info in cls.info().items():
            where, src = f"{cls.__module__}.{cls.__name__}.{name}", info.source.strip()
            if not info.unit:
                bad.append(f"{where}: no unit")
            if not (_THESIS_CITATION.search(src) or _CHOSEN.match(src)):
                bad.append(f"{where}: source {src!r} neither cites the thesis nor says 'chosen: why'")
            bad += [f"{where}: source cites {f!r}, not a file of the repository"
                    for f in _FILE.findall(src) if Path(f).name not in tracked]
            if _NOTES.search(src):
                bad.append(f"{where}: source cites MODEL_NOTES (a chapter map outside the repository), not the thesis")
        assert provenance_table(inst).count("\n") >= 2
    assert not bad, "\n".join(bad)


def test_the_provenance_rule_rejects_what_it_should():
    assert not _THESIS_CITATION.search("issue 6: 10 s datasets") and not _CHOSEN.match("chosen")
    assert not _THESIS_CITATION.search("see the (equation) in eq form") and not _CHOSEN.match("chosen: why")
    for ok in ("Table 3.3", "Fig 4.10 range", "(12.8)", "Tables 14.2, 15.1", "section 5.2.2", "ch. 9",
               "Algorithm 2"):
        assert _THESIS_CITATION.search(ok), ok
    assert _FILE.findall("see MODEL_NOTES.md") == ["MODEL_NOTES.md"]
    assert _NOTES.search("MODEL_NOTES ch. 5: radii") and not _NOTES.search("Table 5.1 M98")


@pytest.mark.parametrize("cls, field, value, message", [
    (MotorParams, "inertia", float("nan"), "MotorParams.inertia = nan is not finite"),
    (MotorParams, "inertia", -2e-3, "must be > 0.0"),
    (FlexibleJointParams, "stiffness", 0.0, "FlexibleJointParams.stiffness = 0.0 is out of range"),
    (JointRigParams, "link_pulley_radius", 0.2, "must be <= 0.05"),
    (MotorParams, "friction", "yes", "must be True or False"),
    (MotorParams, "friction", 0.5, "must be True or False"),
    (MotorParams, "inertia", False, "is not a number"),
    (FlexibleJointParams, "spring_model", "cubic", "must be one of 'linear', 'nonlinear'"),
])
def test_bad_parameters_raise_naming_the_field(cls, field, value, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        cls(**{field: value})


def test_int_fields_take_whole_numbers_only():
    from awiwi_drake.parameters import SpringModelParams
    with pytest.raises(ValueError, match="SpringModelParams.polynomial_degree = 2.5 must be a whole number"):
        SpringModelParams(polynomial_degree=2.5)
    with pytest.raises(ValueError, match="cannot parse '5.5'"):
        JointRigParams().with_overrides({"polynomial_degree": "5.5"})


def test_infeasible_operating_points_and_unused_fields_are_rejected():
    from awiwi_drake.diagrams import build_target
    with pytest.raises(ValueError, match="pretension = 700.0 N exceeds the calibrated range"):
        build_target("joint-rig", {"pretension": "700"})
    with pytest.raises(ValueError, match="beyond motor.torque_limit = 0.05 Nm"):
        build_target("joint-rig", {"torque_limit": "0.05"}).operating_point()
    with pytest.raises(ValueError, match="only apply to spring_model='nonlinear'"):
        build_target("flexible-joint", {"pretension": "5"})
    with pytest.raises(ValueError, match="beyond the lever's mechanical stop"):
        build_target("tendon-rig", {"spring.max_force": "1000"})


def test_spring_overrange_is_reported_and_the_curve_stays_monotonic_beyond_it():
    rig = tendon_rig()
    ctx = rig.context()
    rig.diagram.GetInputPort("motor_torque").FixValue(ctx, [2.9])   # inside the 3 Nm limit: stalls near 600 N
    res = simulate(rig.diagram, ctx, 0.3, log=("tendon_force", "tendon_stiffness"), monitors=rig_monitors(rig))
    over = res.events_of("spring_overrange")
    assert len(over) == 1 and over[0].extreme > rig.spring.max_force
    assert np.all(res["tendon_stiffness"] > 0)            # the tangent continuation never turns over
    assert not res.events_of("actuator_saturation")


def test_pair_slack_of_the_nonlinear_flexible_joint_is_detected():
    rig = flexible_joint_rig(spring="nonlinear")
    x0, r = rig.pair_slack
    ctx = rig.context()
    d = 1.5 * x0 / r                                      # deflection beyond the slack limit x0 / r
    ctx.SetContinuousState([0.0, 0.0, d, 0.0])
    res = simulate(rig.diagram, ctx, 1e-4, log=("state",), monitors=rig_monitors(rig))
    assert [e.channel for e in res.events_of("tendon_slack")] == ["pair tendon 2"]


def test_overrides_reach_nested_parameters_and_reject_unknown_names():
    p = TendonRigParams().with_overrides({"inertia": "3e-3", "spring.geometry.spring_constant": "1e4"})
    assert p.motor.inertia == 3e-3 and p.spring.geometry.spring_constant == 1e4
    assert dataclasses.replace(p).motor.inertia == 3e-3
    with pytest.raises(ValueError, match="unknown parameter 'intertia'"):
        TendonRigParams().with_overrides({"intertia": "1"})


def test_fixed_step_rk3_at_the_control_period_matches_error_control():
    rig = joint_rig()
    op = rig.operating_point(pretension=20.0)
    finals = []
    for fixed in (False, True):
        ctx = rig.context(op)
        rig.diagram.GetInputPort("motor_torque").FixValue(ctx, op.motor_torque + [0.8, -0.8])
        res = simulate(rig.diagram, ctx, 0.1, log=("state",), max_step=1 / 3000, accuracy=1e-7,
                       mode="fixed_step" if fixed else "error_controlled")
        finals.append(res["state"][-1])
        if fixed:
            assert np.allclose(np.diff(res.t[1:]), 1 / 3000)   # really fixed steps
    np.testing.assert_allclose(finals[1], finals[0], rtol=1e-3, atol=1e-5)
