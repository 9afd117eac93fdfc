"""Fig 15.24/15.25 on the index finger's PIP: 3 kHz loops, estimated joint angles, the joints' stick-slip friction."""

import numpy as np
import pytest

from awiwi_drake.parameters import PipStudy
from awiwi_drake.reproductions.ch15_pip_experiments import PIP, pip_experiment, pip_rig, stuck_intervals


def test_pip_sticks_at_the_sines_turning_point_and_slides_at_the_coulomb_level():
    """The plain 15.5 backstepping tracking Fig 15.25's sine up to its first turning point (t = 0.25 s) and past it.

    Without the joints' friction the PIP turns smoothly: it is slower than the Stribeck velocity v_s only while its
    own acceleration carries it through zero speed, ``2 v_s / |qdd|`` (its measured acceleration at the turn).  With
    it the PIP stands at the turn until the loop has reversed the friction from sliding one way (``-Fc``) to sliding
    the other (``+Fc``): with the joint still, the law's torque on it changes only through the reference, at most at
    ``Kp_PIP A omega`` (``Kp`` the law's designed stiffness, the sine's peak rate), so the stand lasts at least
    ``2 Fc / (Kp_PIP A omega)``.  While it slides the friction is the Stribeck level, between Fc and Fs."""
    from awiwi_drake.control import make_controller
    s = PipStudy()
    jp = pip_rig().params.joint_friction_params
    T = 0.5
    on = pip_experiment("backstepping", "sine", t_final=T)
    off = pip_experiment("backstepping", "sine", joint_friction=False, t_final=T)
    v_s = jp.stribeck_velocity
    turn = (off.t > 0.15) & (off.t < 0.45)
    k = np.flatnonzero(turn)[np.argmin(np.abs(off.velocity[turn]))]
    qdd = abs(np.gradient(off.velocity, off.t)[k])
    free = max(d for t0, d in stuck_intervals(off, v_s) if t0 > 0.1)
    assert free <= 2 * v_s / qdd + 2 * (off.t[1] - off.t[0])
    rig = pip_rig()
    op = rig.operating_point(pretension=s.sine_pretension, joint_angles=[0, 0, s.sine_offset, 0])
    kp = make_controller("backstepping", rig, op=op).law.Kp[PIP, PIP]
    omega = 2 * np.pi * s.sine_frequency
    stands = [d for t0, d in stuck_intervals(on, v_s) if 0.15 < t0 < 0.4]
    assert max(stands) >= 2 * jp.coulomb / (kp * s.sine_amplitude * omega)
    assert max(stands) > free
    sliding = (np.abs(on.velocity) > 20 * v_s) & (on.t > 0.05)
    assert np.all(np.abs(on.friction) <= jp.static)
    assert np.all(np.abs(on.friction[sliding]) >= 0.99 * jp.coulomb)
    assert np.all(np.sign(on.friction[sliding]) == -np.sign(on.velocity[sliding]))


def test_pip_experiment_rejects_unknown_tests():
    with pytest.raises(ValueError, match="test must be 'step' or 'sine', got 'ramp'"):
        pip_experiment("cascaded", "ramp")
