"""Finger datasets and the finger diagnosis (issue 12 item 5): the package's finger diagram with one
hidden effect on one tendon; the diagnosis names effect and place, and nothing when nothing is hidden."""

import json
import numpy as np
import pytest

from awiwi_drake.discrepancy import diagnose, load_dataset, save_dataset
from awiwi_drake.discrepancy.finger import FingerResiduals, _kernel
from awiwi_drake.discrepancy.finger_truth import make_finger_dataset
from awiwi_drake.parameters.discrepancy import DiscrepancySettings, FingerTruthParams

SHORT = FingerTruthParams(duration=1.0)
THREE = FingerTruthParams(duration=3.0)   # the shortest record with enough filtered samples (3-fold CV)


@pytest.fixture(scope="module")
def friction_on_5():
    return make_finger_dataset("index", ["motor_friction"], place=5, seed=3, gen=SHORT, snr_db=None)


def test_finger_dataset_is_the_finger_diagram_with_the_effect_at_its_place(friction_on_5):
    """Noise-free: the motor equation of the package's motor law (B w' = u - r f, ideal motor) holds on every
    motor but the hidden one; there the missing torque is the truth's Stribeck friction (sign: opposing w)."""
    ds = friction_on_5
    dt = ds.dt
    B, r = 2e-3, 5e-3
    err = []
    for i in range(8):
        th = ds.outputs[f"motor_angle_{i + 1}"]
        u = ds.inputs[f"motor_torque_{i + 1}"]
        f = ds.outputs[f"tendon_force_{i + 1}"]
        # interval k: theta_{k+1} - 2 theta_k + theta_{k-1} ~ dt^2 acc; u_k held on [t_k, t_k+1)
        acc = (th[2:] - 2 * th[1:-1] + th[:-2]) / dt ** 2
        tau = u[1:-1] - r * f[1:-1] - B * acc
        err.append(np.sqrt(np.mean(tau[50:] ** 2)))
    err = np.array(err)
    assert np.argmax(err) == 4
    # the other motors: the finite-difference error of the nominal law only (far below the friction)
    assert np.all(np.delete(err, 4) < 0.2 * err[4])
    assert ds.meta["truth"]["tendon"] == "index_h5"


def test_finger_dataset_round_trip_and_bad_input(tmp_path, friction_on_5):
    path = save_dataset(friction_on_5, tmp_path)
    ds = load_dataset(path)
    assert ds.rig == "finger-index" and ds.spec.num_motors == 8
    assert "joint_angle_1" not in ds.outputs and json.loads(path.with_suffix(".truth.json").read_text())["place"] == 5
    np.testing.assert_allclose(ds.inputs["motor_torque_3"], friction_on_5.inputs["motor_torque_3"], rtol=1e-9,
                               atol=1e-12)
    meta = json.loads(path.with_suffix(".json").read_text())
    meta["parameters"]["finger_rig"]["motor"]["inertia"] = -1.0
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(meta))
    (tmp_path / "bad.csv").write_text(path.read_text())
    with pytest.raises(ValueError, match="bad.json: parameters.finger_rig.*inertia"):
        load_dataset(tmp_path / "bad.csv")


def test_make_dataset_cli_finger_needs_a_place(tmp_path, capsys):
    from awiwi_drake.cli import main
    code = main(["make-dataset", "--rig", "finger-index", "--hide", "guide_friction", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2 and "--place" in err and len(err.strip().splitlines()) == 1


def test_consistent_filter_kernel_moments():
    """The sampled kernel is a derivative filter to round-off: weights sum to 1 / 0 / 0, first moments give
    the derivative of a ramp, second moments the second derivative of a parabola (a cut at 4 sigma fails:
    sum of H'' = -3e-4/sigma^2 turns a 1 rad motor offset into a 0.03 N m residual)."""
    dt, sigma = 1e-3, 0.02
    s, g0, g1, g2 = _kernel(sigma, dt)
    # _filter(y, w)[i] = sum_j w(t_i - t_j) y_j, so y = t gives sum w(s) (t_i - s)
    assert abs(g0.sum() - 1) < 1e-12 and abs(g1.sum()) < 1e-12 and abs(g2.sum()) < 1e-12 / sigma ** 2
    assert abs(-(g1 * s).sum() - 1) < 1e-6                   # d/dt of t (the cut at 6 sigma: 6e-8)
    assert abs((g2 * s ** 2).sum() / 2 - 1) < 1e-5            # d2/dt2 of t^2 / 2 (1.2e-6)


def test_consistent_filter_makes_the_motor_law_exact(friction_on_5):
    """Noise-free data: the filtered motor law holds on every motor without an effect to 1e-4 of the torque
    (the package's motor law, the command's hold integrated exactly); on motor 5 the residual is the hidden
    Stribeck friction, of its size."""
    fr = FingerResiduals(friction_on_5, DiscrepancySettings(finger_filter=0.008))
    size = np.sqrt(np.mean(fr.torque ** 2, axis=1))
    res = np.sqrt(np.mean(fr.tau ** 2, axis=1))
    others = np.delete(res / size, 4)
    assert np.all(others < 1e-4), others
    p = friction_on_5.meta["truth"]["motor_friction"]
    assert 0.3 * p["fc"] < res[4] < 1.5 * p["fs"]


@pytest.fixture(scope="module")
def friction_noisy(tmp_path_factory):
    ds = make_finger_dataset("index", ["motor_friction"], place=5, seed=11, gen=THREE)
    return save_dataset(ds, tmp_path_factory.mktemp("finger"))


def test_finger_diagnosis_names_effect_and_place(friction_noisy, tmp_path, capsys):
    """30 dB, 3 s: the hidden friction on index_h5 is named with its place through the CLI (JSON and report);
    it is the Stribeck form, so the atan law (3.8) leaves an unexplained rest, which is flagged."""
    from awiwi_drake.cli import main
    assert main(["diagnose", str(friction_noisy), "--quiet", "--json", str(tmp_path / "o.json"), "--report",
                 str(tmp_path / "rep")]) == 0
    js = json.loads((tmp_path / "o.json").read_text())
    assert js["named_effects"] == ["motor_friction"] and js["places"] == {"motor_friction": "index_h5 (PIP)"}
    assert "motor_friction on index_h5 (PIP)" in capsys.readouterr().out
    assert (tmp_path / "rep" / "report.md").exists() and (tmp_path / "rep" / "tendons.png").exists()


def test_finger_diagnosis_nothing_hidden_names_nothing():
    """Nothing hidden: no name; recorded joint angles are reported as not used (never dropped silently)."""
    ds = make_finger_dataset("index", [], seed=14, gen=THREE, joint_angles=True)
    lines = []
    dx = diagnose(ds, progress=lines.append)
    assert dx.named_effects == [] and dx.nuisance_corrections == [] and not dx.unexplained_residual
    assert dx.unused_columns == [f"joint_angle_{j}" for j in range(1, 5)]
    assert any("joint_angle_1" in ln and "not used" in ln for ln in lines) and "not used" in dx.text()
