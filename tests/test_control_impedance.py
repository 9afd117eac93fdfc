"""Joint impedance on tendon force control (ch. 11): stiffness achieved and the findings of Fig 11.2-11.4."""

from __future__ import annotations

import numpy as np
import pytest

from _control_plants import autodiff_vs_fd
from awiwi_drake.control.base import closed_loop
from awiwi_drake.control.compare import run_test
from awiwi_drake.control.impedance import ImpedanceLaw, impedance_controller, transmission
from awiwi_drake.parameters import FlexibleJointParams, JointRigParams
from awiwi_drake.parameters.control import ImpedanceParams, compare_test_params
from awiwi_drake.rigs import flexible_joint_rig, joint_rig


def _loop(rig, mode, kp=0.3):
    return closed_loop(rig, impedance_controller(rig, ImpedanceParams(joint_stiffness=kp), mode=mode), rate_hz=3000.0)


@pytest.mark.parametrize("mode", ["two-time-scale", "cascaded"])
def test_impedance_stiffness_is_achieved(mode):
    """At rest the link torque equals tau_des: joint stiffness = Kp_imp exactly (11.4), whatever the spring."""
    rig = flexible_joint_rig(backend="symbolic")
    p = compare_test_params(rig, step_duration=0.3, settle_time=0.0)
    _, m = run_test(_loop(rig, mode, kp=0.45), "disturbance", params=p)
    assert m.stiffness == pytest.approx(0.45, rel=0.01)


def test_motor_pd_stiffness_is_series_of_spring_and_position_loop():
    rig = flexible_joint_rig(backend="symbolic")
    p = compare_test_params(rig, step_duration=0.3, settle_time=0.0)
    _, m = run_test(_loop(rig, "pd"), "disturbance", params=p)
    ip = ImpedanceParams()
    kp_m = rig.params.motor_inertia * ip.motor_bandwidth ** 2
    k = rig.params.stiffness
    assert m.stiffness == pytest.approx(1.0 / (1.0 / k + 1.0 / kp_m), rel=0.01)


def test_fig_11_2_and_11_3_oscillation_grows_with_impedance_and_shrinks_with_mechanical_stiffness():
    """Two-time-scale impedance on the flexible joint, 0.3 rad step (Fig 11.2, 11.3)."""
    def overshoot(kp, k):
        rig = flexible_joint_rig(params=FlexibleJointParams(stiffness=k), backend="symbolic")
        p = compare_test_params(rig, step_duration=0.2, settle_time=0.0)
        return run_test(_loop(rig, "two-time-scale", kp), "step", params=p)[1].overshoot
    low_imp, high_imp = overshoot(0.3, 0.605), overshoot(1.2, 0.605)
    assert high_imp > low_imp + 10.0  # % of the step
    soft, stiff = overshoot(1.2, 0.43), overshoot(1.2, 1.15)
    assert soft > stiff + 10.0


def test_fig_11_4_resonance_shifts_with_pretension():
    """Simulated chirp 2-20 Hz on the antagonistic joint (cascaded impedance): the gain peak moves with pretension."""
    peaks = {}
    for pre in (10.0, 40.0):
        rig = joint_rig(params=JointRigParams(pretension=pre), backend="symbolic")
        p = compare_test_params(rig, sweep_start=2.0, sweep_stop=20.0, sweep_duration=3.0, sweep_amplitude=0.02,
                                settle_time=0.0)
        _, m = run_test(_loop(rig, "cascaded"), "sweep", params=p)
        peaks[pre] = (m.resonance_hz, m.peak_gain)
        assert m.peak_gain > 1.1  # a resonance, not a low-pass
    assert peaks[10.0][0] - peaks[40.0][0] > 0.6  # Hz: the resonance moves (8.3 -> 7.0 Hz linearised)
    assert peaks[40.0][1] > peaks[10.0][1]


def test_impedance_laws_convert_to_autodiff_and_reject_bad_gains():
    rig = joint_rig()
    for mode in ("two-time-scale", "cascaded"):
        ctrl = impedance_controller(rig, mode=mode)
        inputs = {"link_angle_reference": [0.1], "link_angle": [0.05], "link_velocity": [0.2],
                  "motor_velocity": [0.1, -0.1], "tendon_force": [22.0, 18.0], "tendon_stiffness": [9000.0, 8000.0]}
        J_ad, J_fd = autodiff_vs_fd(ctrl, inputs, h=1e-6)
        np.testing.assert_allclose(J_ad, J_fd, rtol=1e-5, atol=1e-7)
    ctrl = impedance_controller(rig, mode="pd")
    J_ad, J_fd = autodiff_vs_fd(ctrl, {"link_angle_reference": [0.1], "state": rig.operating_point().state + 0.01})
    np.testing.assert_allclose(J_ad, J_fd, rtol=1e-6, atol=1e-7)
    with pytest.raises(ValueError, match="joint_stiffness"):
        ImpedanceParams(joint_stiffness=0.0)
    with pytest.raises(ValueError, match="motor_bandwidth"):
        ImpedanceParams(motor_bandwidth=float("nan"))
    with pytest.raises(ValueError, match="mode"):
        ImpedanceLaw(transmission(rig), mode="singular")


def test_fig_11_2_and_11_3_in_the_gain_diagram():
    """Simulated chirp 5-50 Hz (two-time-scale, flexible joint): the resonance peak grows with the impedance
    stiffness and shrinks with the mechanical stiffness (linearised loop: 1.0 -> 1.24; 1.75 -> 1.0)."""
    from awiwi_drake.control.experiments import impedance_sweep

    def peak(kp, k):
        return impedance_sweep("two-time-scale", joint_stiffness=kp, rig="flexible_joint", stiffness=k,
                               f_start=5.0, f_stop=50.0, duration=1.5)["peak_gain"]
    assert peak(1.2, 0.605) > peak(0.3, 0.605) + 0.2
    assert peak(1.2, 0.43) > peak(1.2, 1.15) + 0.5
