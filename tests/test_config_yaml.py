"""Parameter sets as YAML (Drake's yaml_load_typed / yaml_dump_typed) and ``--config FILE`` on the CLI."""

from __future__ import annotations

import inspect
import json

import numpy as np
import pytest

import awiwi_drake.parameters as P
from awiwi_drake.cli import main
from awiwi_drake.parameters.base import Parameters
from awiwi_drake.parameters.yaml_io import from_yaml, load_yaml, save_yaml, to_yaml
from awiwi_drake.diagrams import TARGETS

ALL_SETS = [c for _, c in inspect.getmembers(P, inspect.isclass) if issubclass(c, Parameters) and c is not Parameters]


@pytest.mark.parametrize("cls", ALL_SETS, ids=lambda c: c.__name__)
def test_every_parameter_set_round_trips(cls):
    p = cls()
    assert from_yaml(cls, to_yaml(p)) == p


def test_changed_values_survive_and_partial_yaml_keeps_defaults(tmp_path):
    from awiwi_drake.parameters import FingerRigParams, JointRigParams

    p = JointRigParams().with_overrides({"pretension": "41", "motor.inertia": "0.0031"})
    path = save_yaml(p, tmp_path / "j.yaml")
    assert load_yaml(JointRigParams, path) == p
    part = from_yaml(JointRigParams, "motor:\n  inertia: 0.004\n")
    assert part.motor.inertia == 0.004 and part.pretension == JointRigParams().pretension
    assert part.motor.torque_limit == JointRigParams().motor.torque_limit      # nested defaults kept
    # a union field (thumb vs finger parameter classes) is tagged and read back as the right class
    thumb = FingerRigParams.for_finger("thumb")
    text = to_yaml(thumb)
    assert "!ThumbParams" in text and from_yaml(FingerRigParams, text) == thumb


@pytest.mark.parametrize("rig", list(TARGETS))
def test_params_yaml_round_trips_through_the_cli(rig, tmp_path, capsys):
    """`awiwi-drake params RIG --yaml > f.yaml` then `--config f.yaml` gives the same parameter set."""
    defaults = TARGETS[rig]["params"]()
    name = "pretension" if "pretension" in defaults.all_names() else "motor.inertia"
    assert main(["params", rig, "--yaml", "--set", f"{name}=0.0037"]) == 0
    text = capsys.readouterr().out
    f = tmp_path / "p.yaml"
    f.write_text(text)
    loaded = load_yaml(defaults, f)
    assert loaded == defaults.with_overrides({name: "0.0037"}) and loaded != defaults
    assert main(["params", rig, "--yaml", "--config", str(f)]) == 0
    assert capsys.readouterr().out == text


def test_linearize_with_config_equals_set(tmp_path, capsys):
    f = tmp_path / "c.yaml"
    f.write_text("pretension: 35\n")
    assert main(["linearize", "joint-rig", "--json", "--config", str(f)]) == 0
    a = json.loads(capsys.readouterr().out)
    assert main(["linearize", "joint-rig", "--json", "--set", "pretension=35"]) == 0
    b = json.loads(capsys.readouterr().out)
    assert main(["linearize", "joint-rig", "--json"]) == 0
    c = json.loads(capsys.readouterr().out)
    np.testing.assert_allclose(a["A"], b["A"], rtol=1e-12)
    assert not np.allclose(a["A"], c["A"])          # the config changed the stiffness
    # --set applies after --config
    assert main(["params", "joint-rig", "--config", str(f), "--set", "pretension=36"]) == 0
    assert "| `pretension` | 36.0 |" in capsys.readouterr().out


def test_yaml_rejects_unknown_keys_wrong_types_and_bad_values():
    from awiwi_drake.parameters import JointRigParams

    for text, message in [("nope: 1", "^x.yaml: unknown key 'nope' "), ("motor: {inertai: 1}", "unknown key 'motor.inertai'"), ("pretension: true", "pretension"),
                          ("pretension: -5", "out of range"), ("motor: {inertia: 1e30}", "implausible"),
                          ("motor: 5", "does not fit"), ("[1, 2", "while parsing")]:
        with pytest.raises(ValueError, match=message):
            from_yaml(JointRigParams, text, where="x.yaml")
    # a named override entry (one set per tendon) names the entry it came from
    from awiwi_drake.parameters.hand import FingerRigParams
    with pytest.raises(ValueError, match=r"^x.yaml: tendon_motors\['index_h3'\]: MotorParams.coulomb_torque = -0.05"):
        from_yaml(FingerRigParams.for_finger("index"), "tendon_motors:\n  index_h3: {coulomb_torque: -0.05}\n",
                  where="x.yaml")
    # an unknown key inside a nested set or a named entry is named with its path (Drake names only the key)
    for text, path in [("tendon_motors: {index_h5: {coulomb_torq: 0.1}}", "tendon_motors.index_h5.coulomb_torq"),
                       ("spring: {hysteresis: {widht_ratio: 0.1}}", "spring.hysteresis.widht_ratio"),
                       ("finger: !IndexFingerParams {mcp_radiu: 0.01}", "finger.mcp_radiu")]:
        with pytest.raises(ValueError, match=rf"^x.yaml: unknown key '{path}' \(known there: .*\)$"):
            from_yaml(FingerRigParams.for_finger("index"), text, where="x.yaml")
    # an unknown tendon is refused at load (not first at build), naming the file and the key; the names are the
    # finger's coupling rows (FingerRigParams.tendon_names = finger_coupling(...).tendon_names for every finger)
    for text in ("tendon_motors: {index_h9: {coulomb_torque: 0.1}}", "tendon_springs: {thumb_h1: {}}"):
        with pytest.raises(ValueError, match=r"^x.yaml: FingerRigParams.tendon_(motors|springs): unknown tendon "
                                             r"'(index_h9|thumb_h1)'; tendons are index_h1 ... index_h8$"):
            from_yaml(FingerRigParams.for_finger("index"), text, where="x.yaml")
    from awiwi_drake.hand.coupling import finger_coupling, hand_coupling
    from awiwi_drake.parameters.hand import FINGERS, HandRigParams
    for f in FINGERS:
        assert FingerRigParams.for_finger(f).tendon_names == list(finger_coupling(f).tendon_names)
    assert sorted(HandRigParams().tendon_names) == sorted(hand_coupling().tendon_names)


def test_progress_is_quiet_unless_asked(monkeypatch, capsys):
    """Progress bars: off when quiet, piped or in short mode; on with AWIWI_PROGRESS=1."""
    from awiwi_drake.config import SimulationProgress, progress_enabled

    monkeypatch.delenv("AWIWI_PROGRESS", raising=False)
    assert progress_enabled(quiet=True) is False
    monkeypatch.setenv("AWIWI_SHORT", "1")
    assert progress_enabled() is False
    monkeypatch.setenv("AWIWI_PROGRESS", "1")
    assert progress_enabled() is True and progress_enabled(quiet=True) is False
    with SimulationProgress("run") as p:
        p(0.5, 1.0)
        p(1.0, 1.0)
    err = capsys.readouterr().err
    assert "run" in err and "1/1 s simulated" in err
    monkeypatch.setenv("AWIWI_PROGRESS", "0")
    with SimulationProgress("run") as p:
        p(0.5, 1.0)
    assert capsys.readouterr().err == ""
