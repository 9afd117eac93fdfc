"""Motor level (ch. 3): friction identification (Fig 3.3, (3.8)) and ripple compensation (Fig 3.5-3.6)."""

from __future__ import annotations

import numpy as np
import pytest

from _fd import autodiff_vs_fd, fd_jacobian
from awiwi_drake.components import atan_friction
from awiwi_drake.control.base import StaticLawController
from awiwi_drake.control.motor_compensation import MotorPdLaw
from awiwi_drake.reproductions.ch03_motor import (fit_friction, friction_identification_data, harmonic,
                                                  ripple_compensation_experiment)
from awiwi_drake.parameters import MotorParams
from awiwi_drake.parameters.control import FrictionIdentificationParams, RippleCompensationParams


def test_friction_identification_recovers_table_3_3():
    """Simulated Fig 3.3 protocol (ripple on, torque noise 0.05 Nm, every plateau from rest at zero torque):
    the (3.8) parameters of Table 3.3 lie within three standard errors of the least-squares fit (standard
    errors from the fit's Jacobian and its residual, not from the true values)."""
    motor = MotorParams(ripple=True)  # Table 3.3: gamma1 = 10, gamma2 = 0.5586, gamma3 = 0.0356
    p = FrictionIdentificationParams(num_speeds=6, plateau_time=0.45)
    data = friction_identification_data(motor, p, seed=3)
    fit = fit_friction(data.speed, data.torque)
    g = np.array([fit.gamma1, fit.gamma2, fit.gamma3])
    model = lambda g_: -atan_friction(data.speed, g_[1], g_[0], g_[2])   # torque needed to turn, (3.8)
    J = fd_jacobian(model, g)
    sigma = np.sqrt(np.sum((model(g) - data.torque) ** 2) / (data.speed.size - 3))
    standard_error = sigma * np.sqrt(np.diag(np.linalg.inv(J.T @ J)))
    true = np.array([motor.friction_slope, motor.coulomb_torque, motor.viscous_friction])
    assert np.all(np.abs(g - true) < 3.0 * standard_error), ((g - true) / standard_error)
    assert np.all(standard_error < 0.1 * true)            # and the protocol resolves each parameter to 10 %
    # the plateau means average the noise and whole motor-shaft ripple periods: what is left cannot exceed
    # the two ripple amplitudes
    assert fit.rms_residual < motor.ripple_motor_amplitude + motor.ripple_output_amplitude
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
    """Fig 3.5-3.6b. Without compensation the PD's first harmonic is the ripple torque through the closed
    loop, ``a_m |Kp + j w Kd| / |Kp - B w^2 + j w (Kd + d)|`` at ``w = N v`` (friction compensated); with 80 %
    of the *identified* ripple fed forward it falls to ``|1 - 0.8 (a^/a) e^(j(phi^ - phi))|``. The 3 kHz
    sample-and-hold shifts the loop by at most one sample of phase, ``w T_s`` (3.3 %): the tolerance, also of the
    identification from the sampled torque balance (one sample of phase; the hold's amplitude error is second
    order, ``(w T_s)^2 / 24``)."""
    motor = MotorParams(ripple=True)
    p = RippleCompensationParams(amplitude_scale=0.8, duration=0.6)
    res = ripple_compensation_experiment(motor, p)
    w = motor.gear_ratio * p.speed
    tol = w / 3000.0
    # identification at the known period: amplitude and phase of the motor-shaft bearing ripple
    assert res.estimate.ripple_motor_amplitude == pytest.approx(motor.ripple_motor_amplitude, rel=tol)
    assert abs(np.angle(np.exp(1j * (res.estimate.ripple_motor_phase - motor.ripple_motor_phase)))) <= tol
    assert res.first_harmonic_hz == pytest.approx(w / (2 * np.pi))
    s = 1j * w
    loop = (p.position_gain + p.velocity_gain * s) / (motor.inertia * s * s + motor.damping * s + p.position_gain
                                                      + p.velocity_gain * s)
    assert res.amplitude_without == pytest.approx(motor.ripple_motor_amplitude * abs(loop), rel=tol)
    e = res.estimate
    left = abs(1.0 - p.amplitude_scale * e.ripple_motor_amplitude / motor.ripple_motor_amplitude
               * np.exp(1j * (e.ripple_motor_phase - motor.ripple_motor_phase)))
    assert res.attenuation == pytest.approx(left, rel=tol)
    # the spectrum peak at the motor rotation frequency drops accordingly
    k = np.argmin(np.abs(res.frequency - res.first_harmonic_hz))
    assert res.spectrum_with[k] < 0.3 * res.spectrum_without[k]


def test_harmonic_extracts_complex_amplitude():
    t = np.arange(0, 1.0, 1e-3)
    y = 0.3 * np.sin(2 * np.pi * 16 * t + 0.4) + 0.1 * t + 2.0
    assert harmonic(t, y, 16.0) == pytest.approx(0.3 * np.exp(0.4j), abs=1e-9)


def test_motor_pd_law_autodiff_and_bad_gains():
    law = MotorPdLaw(MotorParams(ripple=True), 5.0, 0.2, friction_scale=1.0, ripple=MotorParams(
        ripple=True, ripple_motor_amplitude=0.05, ripple_motor_phase=0.3, ripple_output_amplitude=0.0))
    J_ad, J_fd = autodiff_vs_fd(StaticLawController(law), {"motor_angle_reference": [0.4], "motor_velocity_reference": [1.0],
                                                           "motor_angle": [0.39], "motor_velocity": [0.9]})
    np.testing.assert_allclose(J_ad, J_fd, rtol=1e-6, atol=1e-7)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="position_gain"):
            MotorPdLaw(MotorParams(), bad, 0.2)
    with pytest.raises(ValueError, match="amplitude_scale"):
        RippleCompensationParams(amplitude_scale=1.5)


def test_3_6_inertia_identification_closed_form_and_friction_bias():
    """(3.6) B thdd = k_t i: without friction the fit returns B exactly; with the (3.8) friction the
    thesis neglects, each single-current fit is biased upwards and less so at larger currents (the
    Coulomb torque is a smaller share), and differencing the currents removes most of the bias."""
    from awiwi_drake.reproductions.ch03_motor import inertia_identification
    clean = inertia_identification(motor=MotorParams(friction=False))
    np.testing.assert_allclose(clean.identified, clean.true, rtol=1e-6)
    real = inertia_identification()
    err = real.relative_error
    assert np.all(err > 0.2) and np.all(np.diff(err) < 0)
    assert abs(real.from_difference / real.true - 1) < 0.5 * err.min()


def test_fig_3_3b_current_axis_uses_the_torque_constant():
    from awiwi_drake.components import motor_friction_torque
    from awiwi_drake.reproductions.ch03_motor import friction_curve_in_ampere
    p = MotorParams()
    v = np.array([-15.0, -3.0, 0.0, 3.0, 15.0])
    i = friction_curve_in_ampere(v, p)
    np.testing.assert_allclose(i * p.torque_constant, -motor_friction_torque(v, p), rtol=1e-12)
    np.testing.assert_allclose(i, -i[::-1], atol=1e-15)                  # central symmetry of (3.8)
    # the torque constant: (3.8) with Table 3.3 at Fig 3.3b's full speed over the current read there
    from awiwi_drake.parameters.components import FIG_3_3B_FULL_SPEED_CURRENT
    speed, current = FIG_3_3B_FULL_SPEED_CURRENT
    assert p.torque_constant == round(float(-motor_friction_torque(np.array([speed]), p)[0]) / current, 4) == 1.0829
