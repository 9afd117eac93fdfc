"""Fig 15.24/15.25: PIP of a finger, antagonistic backstepping vs cascaded, 3 kHz, stick-slip link friction."""

import numpy as np
import pytest

from awiwi_drake.reproductions.ch15_pip_experiments import pip_experiment, pip_metrics, pip_parameters


def test_pip_parameters_come_from_the_finger():
    from awiwi_drake.hand.plant import make_finger_plant
    from awiwi_drake.parameters.hand import finger_params
    p = pip_parameters(10.0)
    fp = finger_params("index")
    assert p.link_pulley_radius == fp.pip_radius and p.pretension == 10.0
    # middle + distal about the PIP (straight finger): cylinders about the PIP axis, parallel axis theorem;
    # the distal link's lateral offset (M76 z) lies along the joint axis and adds nothing
    R, Lm, Ld = fp.link_radius, fp.middle_length, fp.distal_length
    assert fp.middle_lateral != 0.0
    I = (fp.middle_mass * (Lm ** 2 / 3 + R ** 2 / 4)
         + fp.distal_mass * (Ld ** 2 / 12 + R ** 2 / 4 + (Lm + Ld / 2) ** 2))
    assert p.link_inertia == pytest.approx(I, rel=1e-7)


def test_step_backstepping_is_more_accurate_than_cascaded_under_stick_slip():
    """Fig 15.24 (30 deg step, 10 N, 3 kHz): the backstepping link settles without overshoot and ends
    closer to the target; the cascaded link overshoots and reverses repeatedly (stick-slip)."""
    bs = pip_metrics(pip_experiment("backstepping", "step", t_final=0.6))
    ca = pip_metrics(pip_experiment("cascaded", "step", t_final=0.6))
    assert bs["overshoot"] < 1.0 < ca["overshoot"]
    assert bs["final_error"] < 0.5 * ca["final_error"]
    assert ca["reversals_per_s"] > 10 * max(bs["reversals_per_s"], 1.0)
    for m in (bs, ca):
        assert m["min_tendon_force"] > 5.0 and m["peak_torque"] <= 3.0 + 1e-9
