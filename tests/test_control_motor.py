"""Motor level (ch. 3): friction identification (Fig 3.3, (3.8)) and ripple compensation (Fig 3.5-3.6)."""

from __future__ import annotations

import numpy as np
import pytest

from _control_plants import autodiff_vs_fd
from awiwi_drake.control.base import StaticLawController
from awiwi_drake.control.motor_compensation import MotorPdLaw, RippleEstimate
from awiwi_drake.reproductions.ch03_motor import (fit_friction, friction_identification_data, harmonic,
                                                  ripple_compensation_experiment)
from awiwi_drake.parameters import MotorParams
from awiwi_drake.parameters.control import FrictionIdentificationParams, RippleCompensationParams


def test_friction_identification_recovers_table_3_3():
    """Simulated Fig 3.3 protocol (ripple on, torque noise 0.05 Nm, every plateau from rest at zero torque):
    (3.8) parameters within 4 / 1.5 / 5 % (about 3x the largest error over seeds 0-4: 1.2 / 0.4 / 1.8 %)."""
    motor = MotorParams(ripple=True)  # Table 3.3: gamma1 = 10, gamma2 = 0.5586, gamma3 = 0.0356
    p = FrictionIdentificationParams(num_speeds=6, plateau_time=0.45)
    assert p.torque_noise_std == 0.05
    data = friction_identification_data(motor, p, seed=3)
    fit = fit_friction(data.speed, data.torque)
    assert fit.gamma1 == pytest.approx(motor.friction_slope, rel=0.04)
    assert fit.gamma2 == pytest.approx(motor.coulomb_torque, rel=0.015)
    assert fit.gamma3 == pytest.approx(motor.viscous_friction, rel=0.05)
    assert fit.rms_residual < 0.02  # Nm; the ripple residue of the plateau means (0.011 observed)
    # central symmetry (3.8): the fitted law is odd
    np.testing.assert_allclose(fit.torque(-data.speed), -fit.torque(data.speed))


def test_fit_friction_exact_on_noise_free_law_and_rejects_bad_data():
    w = np.concatenate([-np.geomspace(0.05, 15, 8)[::-1], np.geomspace(0.05, 15, 8)])
    tau = 0.4 * np.arctan(7.0 * w) + 0.02 * w
    fit = fit_friction(w, tau)
    np.testing.assert_allclose([fit.gamma1, fit.gamma2, fit.gamma3], [7.0, 0.4, 0.02], rtol=1e-5)
    with pytest.raises(ValueError, match="finite"):
        fit_friction(w, np.where(w > 1, np.nan, tau))
    with pytest.raises(ValueError, match=">= 3"):
        fit_friction([1.0, 2.0], [0.1, 0.2])


def test_ripple_compensation_attenuates_first_harmonic_by_the_conservative_factor():
    """Feed-forward with 80 % of the identified ripple leaves ~20 % of the first harmonic (Fig 3.6b)."""
    motor = MotorParams(ripple=True)
    res = ripple_compensation_experiment(motor, RippleCompensationParams(amplitude_scale=0.8, duration=0.6))
    # identification at the known period: amplitude and phase of the motor-shaft bearing ripple
    assert res.estimate.motor_amplitude == pytest.approx(motor.ripple_motor_amplitude, rel=0.02)
    assert abs(np.angle(np.exp(1j * (res.estimate.motor_phase - motor.ripple_motor_phase)))) < 0.02
    assert res.first_harmonic_hz == pytest.approx(100 * 1.0 / (2 * np.pi))
    assert res.attenuation == pytest.approx(0.2, abs=0.04)
    # the spectrum peak at the motor rotation frequency drops accordingly
    k = np.argmin(np.abs(res.frequency - res.first_harmonic_hz))
    assert res.spectrum_with[k] < 0.3 * res.spectrum_without[k]


def test_harmonic_extracts_complex_amplitude():
    t = np.arange(0, 1.0, 1e-3)
    y = 0.3 * np.sin(2 * np.pi * 16 * t + 0.4) + 0.1 * t + 2.0
    assert harmonic(t, y, 16.0) == pytest.approx(0.3 * np.exp(0.4j), abs=1e-9)


def test_motor_pd_law_autodiff_and_bad_gains():
    law = MotorPdLaw(MotorParams(ripple=True), 5.0, 0.2, friction_scale=1.0, ripple=RippleEstimate(0.05, 0.3))
    J_ad, J_fd = autodiff_vs_fd(StaticLawController(law), {"motor_angle_reference": [0.4], "motor_velocity_reference": [1.0],
                                                           "motor_angle": [0.39], "motor_velocity": [0.9]})
    np.testing.assert_allclose(J_ad, J_fd, rtol=1e-6, atol=1e-7)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="position_gain"):
            MotorPdLaw(MotorParams(), bad, 0.2)
    with pytest.raises(ValueError, match="amplitude_scale"):
        RippleCompensationParams(amplitude_scale=1.5)
