"""Finger datasets and the finger diagnosis (issue 12 item 5): the package's finger diagram with one
hidden effect on one tendon; the diagnosis names effect and place, and nothing when nothing is hidden."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from awiwi_drake.discrepancy import load_dataset, save_dataset
from awiwi_drake.discrepancy.finger_truth import make_finger_dataset
from awiwi_drake.parameters.discrepancy import FingerTruthParams

SHORT = FingerTruthParams(duration=1.0)


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


def test_make_dataset_cli_finger_needs_a_place(tmp_path):
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    out = subprocess.run([sys.executable, "-m", "awiwi_drake", "make-dataset", "--rig", "finger-index", "--hide",
                          "guide_friction", "--out", str(tmp_path)], capture_output=True, text=True, env=env)
    assert out.returncode != 0 and "--place" in out.stderr and len(out.stderr.strip().splitlines()) <= 2
