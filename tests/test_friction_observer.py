"""Joint friction observer (ch. 9): closed-form convergence, conversion, compensation on stick-slip friction."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from _fd import check_system_autodiff_matches_fd
from awiwi_drake.control.friction_observer import DisturbanceObserver, LinkFriction, observer_rate
from awiwi_drake.reproductions.ch09_friction_observer import chattering, friction_tracking_run
from awiwi_drake.parameters.hand_control import FrictionObserverParams, LinkFrictionParams


def test_observer_estimate_is_a_first_order_filter_of_the_disturbance():
    """d_hat' = L (d - d_hat): for a constant d from rest, d_hat(t) = d (1 - exp(-L t))."""
    J, L, d, tau = 1e-5, 50.0, 0.02, 0.01
    obs = DisturbanceObserver(J, FrictionObserverParams(gain=L))
    ctx = obs.CreateDefaultContext()
    sim = Simulator(obs, ctx)
    obs.get_input_port(1).FixValue(ctx, [tau])
    # the link: J w' = tau + d from rest -> w(t) = (tau + d) t / J; feed w(t) piecewise
    w = 0.0
    dt = 1e-4
    for k in range(1, 401):
        t = k * dt
        obs.get_input_port(0).FixValue(ctx, [(tau + d) * t / J])
        sim.AdvanceTo(t)
    d_hat = obs.get_output_port().Eval(ctx)[0]
    assert d_hat == pytest.approx(d * (1 - np.exp(-L * 0.04)), rel=2e-2)
    wdot, dh = observer_rate(0.0, 1.0, 0.0, J, L)
    assert dh == pytest.approx(L * J) and wdot == pytest.approx(L)


def test_systems_convert_and_autodiff_matches_closed_form_derivatives():
    """Observer (9.2) and link friction: AutoDiffXd derivatives equal central differences and the
    closed forms d(w_hat')/dw = L, d(w_hat')/dw_hat = -L - d/J, d d_hat/dw = L J; friction slope
    at v from the Stribeck law written here."""
    J, L, d = 1e-5, 200.0, 3e-6
    obs = DisturbanceObserver(J, FrictionObserverParams(gain=L), damping=d)
    jac = check_system_autodiff_matches_fd(obs, [0.3], {"joint_velocity": [0.5], "joint_torque": [0.01]})
    xdot_ad, _ = jac["xdot"]
    est_ad, _ = jac["disturbance_estimate"]
    # d/d[w_hat, w, tau]: w_hat' = (tau + L J (w - w_hat) - d w)/J  (the estimate's damping is known)
    np.testing.assert_allclose(xdot_ad[0], [-L, L - d / J, 1.0 / J], rtol=1e-12)
    np.testing.assert_allclose(est_ad[0], [-L * J, L * J, 0.0], rtol=1e-12, atol=1e-18)
    p = LinkFrictionParams()
    fr = LinkFriction(p)
    for v in (-0.2, -0.01, 0.0, 0.003, 0.4):
        (J_ad, J_fd), = check_system_autodiff_matches_fd(fr, [], {"joint_velocity": [v]}).values()
        s, e = p.stribeck_velocity, p.smoothing_velocity
        level = p.coulomb + (p.static - p.coulomb) * np.exp(-(v / s) ** 2)
        dlevel = -2 * v / s ** 2 * (p.static - p.coulomb) * np.exp(-(v / s) ** 2)
        slope = -(dlevel * np.tanh(v / e) + level / (e * np.cosh(v / e) ** 2)) - p.viscous
        assert J_ad[0, 0] == pytest.approx(slope, rel=1e-12)


def test_compensation_reduces_the_tracking_error_and_costs_chattering():
    """Fig 9.3: sinusoidal tracking with link stick-slip friction, with and without compensation."""
    runs = {c: friction_tracking_run(compensate=c, t_final=1.2) for c in (False, True)}
    rms = {c: float(np.sqrt(np.mean((r.q - r.reference)[r.t > 0.4] ** 2))) for c, r in runs.items()}
    assert rms[True] < 0.5 * rms[False]
    assert chattering(runs[True], after=0.4) > chattering(runs[False], after=0.4)
