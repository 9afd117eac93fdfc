"""``awiwi-drake compare``: files, rows, physics of one row, errors with exit status 2."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from awiwi_drake.cli import main


def test_compare_writes_metrics_and_plots(tmp_path):
    out = tmp_path / "cmp"
    rc = main(["compare", "--rig", "flexible-joint", "--controllers", "two-time-scale,lqr", "--out", str(out),
               "--short", "--tests", "step,disturbance", "--load", "0.03"])
    assert rc == 0
    rows = list(csv.DictReader((out / "metrics.csv").open()))
    assert [(r["controller"], r["test"]) for r in rows] == [
        ("two-time-scale", "step"), ("two-time-scale", "disturbance"), ("lqr", "step"), ("lqr", "disturbance")]
    assert [float(r["load_torque"]) for r in rows if r["test"] == "disturbance"] == [0.03, 0.03]   # --load
    # the impedance controller holds its stiffness (0.3 Nm/rad, ImpedanceParams) under the torque step. Bound: the
    # deflection is measured on the last 10 % of the run; what it still lacks of its steady value is the decaying
    # mode's rate times its time constant, at most the row's ``drift`` (end rate times the time since the step)
    # while that constant is shorter than the test: rel. error <= drift / deflection (measured 1.3e-5 <= 1.6e-4)
    row = next(r for r in rows if r["controller"] == "two-time-scale" and r["test"] == "disturbance")
    stiff, drift = float(row["stiffness"]), float(row["drift"])
    assert stiff == pytest.approx(0.3, rel=drift / (float(row["load_torque"]) / stiff))
    assert all(r["status"] == "ok" for r in rows if r["controller"] == "two-time-scale")
    for r in rows:  # status flags are consistent with the metrics in the CSV
        assert r["status"] == ("flagged" if r["flags"] else "ok")
        if r["test"] == "step":
            assert ("not settled" in r["flags"]) == (r["settling_time"] == "nan")
    assert "| two-time-scale |" in (out / "metrics.md").read_text()
    assert (out / "step.png").stat().st_size > 1000 and (out / "disturbance.png").exists()


@pytest.mark.parametrize("args,needle", [
    (["--rig", "flexible-joint", "--controllers", "pd,nope"], "unknown controller 'nope'"),
    (["--rig", "flexible-joint", "--controllers", "tendon-pd"], "does not fit rig 'flexible-joint'"),
    (["--rig", "tendon-rig", "--controllers", "tendon-pd", "--tests", "disturbance"], "external torque"),
    (["--rig", "joint-rig", "--controllers", "pd", "--tests", "ramp"], "unknown test 'ramp'"),
    (["--rig", "joint-rig", "--controllers", "pd,pd"], "duplicate"),
])
def test_compare_errors_exit_2(tmp_path, capsys, args, needle):
    rc = main(["compare", *args, "--out", str(tmp_path / "x"), "--short"])
    assert rc == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1


def test_compare_list(capsys):
    assert main(["compare", "--rig", "tendon-rig", "--list"]) == 0
    out = capsys.readouterr().out
    assert [line.split()[0] for line in out.splitlines()] == ["tendon-pd", "tendon-scheduled", "tendon-sdre"]


def test_metrics_markdown_tables_have_one_cell_per_column_also_when_every_row_diverged():
    """A test whose rows all diverged has no numeric column: the header, the delimiter row and every
    row must still have the same number of cells, else the Markdown is not a table."""
    from awiwi_drake.control.compare.metrics import Metrics, MetricsTable
    t = MetricsTable([Metrics("pd", "step", joint="link", status="diverged: state[1] = 6e6"),
                      Metrics("lqr", "sine", joint="link", rise_time=0.01, gain=0.9)])
    md = t.to_markdown(ref_unit="rad")
    for block in md.split("### ")[1:]:
        table = [ln for ln in block.splitlines() if ln.startswith("|")]
        assert len(table) == 3
        cells = [ln.count("|") - 1 for ln in table]
        assert len(set(cells)) == 1, (block, cells)
    assert "| pd | link | diverged: state[1] = 6e6 |" in md
    assert "| controller | joint | rise_time [s] | gain [rad/rad] | status |" in md


@pytest.mark.parametrize("args,needle", [
    (["--controller-set", "bogus=1"], "--controller-set: unknown parameter 'bogus' for CompareControllerParams"),
    (["--controller-set", "distribution_method=nope"], "--controller-set: HandChainParams.distribution_method = 'nope'"),
    (["--controller-set", "joint_stiffness=soft"], "--controller-set: HandChainParams.joint_stiffness: cannot parse"),
    (["--controller-set", "joint_stiffness"], "--controller-set expects NAME=VALUE"),
    (["--controller-set", "joint_stiffness=1", "--controllers", "joint-pd"],
     "--controller-set: controller 'joint-pd' on 'finger-index' takes no chain_params"),
    (["--controller-set", "stiffness_correction=true", "--controllers", "backstepping"],
     "--controller-set: controller 'backstepping' on 'finger-index' takes no stiffness_correction"),
    (["--controller-set", "sdre_weights=0,0"], "HandChainParams.sdre_weights = (0.0, 0.0) must be (q_theta > 0"),
    (["--controller-set", "tendon_law=pid"], "--controller-set: HandChainParams.tendon_law = 'pid' must be one of"),
    (["--controller-set", "tendon_law=sdre", "--controllers", "backstepping"],
     "tendon_law = 'sdre': the 15.5 finger backstepping computes the motor torques itself"),
    (["--sensors", "perfect"], "--sensors: invalid choice: 'perfect'"),
    (["--rig", "joint-rig", "--sensors", "ideal"], "--sensors: only for fingers and the hand, not rig 'joint-rig'"),
    (["--rig", "joint-rig", "--controller-set", "joint_stiffness=1"], "--controller-set: only for fingers"),
])
def test_compare_controller_options_bad_input_exit_2(tmp_path, capsys, args, needle):
    """Bad --controller-set / --sensors: one line naming the option (and key), exit 2, before any simulation."""
    rig = [] if "--rig" in args else ["--rig", "finger-index"]
    ctrl = [] if "--controllers" in args else ["--controllers", "cascaded" if rig else "pd"]
    rc = main(["compare", *rig, *ctrl, *args, "--out", str(tmp_path / "x"), "--short", "--tests", "step"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and needle in err and len(err.splitlines()) == 1, err


def test_compare_controller_set_and_ideal_sensors_reach_the_loop(tmp_path, monkeypatch):
    """--controller-set and --sensors reach the loops the CLI simulates (the simulation itself is stubbed: the
    loops are recorded): the chain's force distribution is Algorithm 2 (ch. 7), its joint stiffness the one set and
    its distribution asked for K_mech = eps K_eff (8.2) with the set eps, its tendon force law the ch. 14 SDRE;
    with --sensors ideal the controller reads the plant's joint state (the tendon-length estimator runs beside it),
    without it the loop estimates (5.15)."""
    import awiwi_drake.control.compare as cmp
    from awiwi_drake.control.compare import standard_tests

    seen = {}

    def record(loops, **kw):
        seen.update(loops)
        return standard_tests.Comparison([], standard_tests.MetricsTable([]), "finger-index")

    monkeypatch.setattr(cmp, "compare", record)
    for tag, extra in (("alg2", ["--controller-set", "distribution_method=algorithm2",
                                 "--controller-set", "joint_stiffness=0.25", "--controller-set",
                                 "stiffness_correction=true", "--controller-set", "epsilon=2", "--controller-set",
                                 "tendon_law=sdre", "--sensors", "ideal"]),
                       ("default", [])):
        rc = main(["compare", "--rig", "finger-index", "--controllers", "cascaded", "--tests", "step", "--short",
                   "--quiet", "--out", str(tmp_path / tag), *extra])
        assert rc == 0
        loop = seen.pop("cascaded")
        design = loop.controller.design
        if tag == "alg2":
            assert design.distribution_method == "algorithm2"
            assert design.joint_design.static_stiffness.max() <= 0.25 + 1e-12   # the set joint_stiffness caps K
            K_mech = np.concatenate([np.diag(B) for B in design.mechanical_stiffness])     # (8.2), eps = 2
            np.testing.assert_allclose(K_mech, 2.0 * design.joint_design.static_stiffness, rtol=1e-12)
            assert loop.estimated == () and loop.fused is None            # the controller reads the true state
            assert loop.diagram.HasOutputPort("joint_angle_estimation_error")  # the estimator runs beside it
            assert "distribution_method=algorithm2" in (tmp_path / tag / "metrics.md").read_text()
            assert loop.controller.HasOutputPort("tendon_sdre_gain")      # the ch. 14 tendon SDRE is the force law
        else:
            assert not loop.controller.HasOutputPort("tendon_sdre_gain")
            assert design.distribution_method == "optimal"
            assert design.joint_design.static_stiffness.max() == pytest.approx(0.5)   # HandChainParams' default
            assert loop.estimator is not None or loop.fused is not None
