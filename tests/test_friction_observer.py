"""Joint friction observer (ch. 9): closed-form convergence, conversion, compensation on stick-slip friction."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from awiwi_drake.control.friction_observer import DisturbanceObserver, LinkFriction, observer_rate, stick_slip_friction
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


def test_systems_convert_and_friction_opposes_motion():
    assert DisturbanceObserver(1e-5).ToAutoDiffXd() is not None
    assert LinkFriction().ToAutoDiffXd() is not None
    p = LinkFrictionParams()
    v = np.linspace(-1, 1, 41)
    f = stick_slip_friction(v, p)
    assert np.all(f * v <= 0)                                   # dissipative
    assert np.max(np.abs(f)) <= p.static + p.viscous * 1.0 + 1e-12


def test_compensation_reduces_the_tracking_error_and_costs_chattering():
    """Fig 9.3: sinusoidal tracking with link stick-slip friction, with and without compensation."""
    runs = {c: friction_tracking_run(compensate=c, t_final=1.2) for c in (False, True)}
    rms = {c: float(np.sqrt(np.mean((r.q - r.reference)[r.t > 0.4] ** 2))) for c, r in runs.items()}
    assert rms[True] < 0.5 * rms[False]
    assert chattering(runs[True], after=0.4) > chattering(runs[False], after=0.4)
