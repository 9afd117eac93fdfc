"""Controller API: closed-loop wiring, delay, sensors, metrics on closed forms, registry, errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from _control_plants import flexible_joint_matrices, linear_flexible_joint_rig
from _fd import autodiff_vs_fd
from awiwi_drake.control.base import StaticLaw, StaticLawController, check_gain, check_gains, closed_loop
from awiwi_drake.analysis import Step, simulate
from awiwi_drake.control.compare import (gain_diagram, run_test, sine_metrics, step_metrics)
from awiwi_drake.control.registry import controller_names, get_entry, register_controller
from awiwi_drake.control.sensors import Quantizer, force_sensor, quantize
from awiwi_drake.control.compare import compare_test_params
from awiwi_drake.parameters.control import ForceSensorParams


class _PassThrough(StaticLaw):
    """u = joint_angle_reference (open loop), to observe the command path."""
    name = "pass"
    inputs = {"joint_angle_reference": 1, "state": 4}
    output_size = 1

    def __call__(self, u):
        return np.array([u["joint_angle_reference"][0] + 0.0 * u["state"][0]])


class _Pd(StaticLaw):
    name = "pd_test"
    inputs = {"joint_angle_reference": 1, "state": 4}
    output_size = 1

    def __init__(self, kp=0.5, kd=0.01):
        self.kp, self.kd = check_gain("kp", kp, owner="pd_test"), check_gain("kd", kd, owner="pd_test")

    def __call__(self, u):
        x = u["state"]
        return np.array([self.kp * (u["joint_angle_reference"][0] - x[0]) - self.kd * x[3]])


def test_closed_loop_ports_and_round_trip_delay():
    loop = closed_loop(linear_flexible_joint_rig(), StaticLawController(_PassThrough()), rate_hz=3000.0,
                       delay=333e-6)
    assert loop.references == ("joint_angle_reference",)
    assert loop.disturbances == ("external_torque",)
    assert loop.delay_steps == 1 and loop.delay == pytest.approx(1 / 3000.0)
    ctx = loop.create_context(motor_torque=0.25, references={"joint_angle_reference": 0.25})
    # the buffers start at the operating-point torque: no kick at t = 0
    assert loop.diagram.GetOutputPort("motor_torque").Eval(ctx)[0] == pytest.approx(0.25)
    dt = 1 / 3000.0
    first = {}
    for delay in (None, 333e-6):
        lp = closed_loop(linear_flexible_joint_rig(), StaticLawController(_PassThrough()), rate_hz=3000.0, delay=delay)
        log = simulate(lp, lp.create_context(motor_torque=0.25, references={"joint_angle_reference": 0.25}), 20 * dt,
                       inputs={"joint_angle_reference": Step(5 * dt, 1.0, before=0.25)},
                       log=("motor_torque", "motor_torque_command"), log_period=dt)
        cmd, applied = log["motor_torque_command"][:, 0], log["motor_torque"][:, 0]
        # the command (feedthrough of the reference) jumps at the step sample; the hold applies it on
        # [t_5, t_6), which the left-limit log shows at t_6
        first[delay] = (int(np.argmax(cmd > 0.5)), int(np.argmax(applied > 0.5)))
    assert first[None] == (5, 6)
    # one period of round-trip delay: the applied torque follows one period later than without delay
    assert first[333e-6] == (5, 7)


def test_closed_loop_rejects_bad_wiring():
    class BadMeas(_PassThrough):
        inputs = {"joint_angle_reference": 1, "joint_torque": 1}

    class BadRef(_PassThrough):
        inputs = {"spring_force_reference": 1, "state": 4}

    class BadSize(_PassThrough):
        inputs = {"joint_angle_reference": 1, "state": 3}

    rig = linear_flexible_joint_rig
    with pytest.raises(ValueError, match="'joint_torque'"):
        closed_loop(rig(), StaticLawController(BadMeas()))
    with pytest.raises(ValueError, match="'spring_force_reference'"):
        closed_loop(rig(), StaticLawController(BadRef()))
    with pytest.raises(ValueError, match="'state' has size 3"):
        closed_loop(rig(), StaticLawController(BadSize()))
    with pytest.raises(ValueError, match="whole number of control periods"):
        closed_loop(rig(), StaticLawController(_Pd()), rate_hz=3000.0, delay=5e-4)
    with pytest.raises(ValueError, match="needs a sampled controller"):
        closed_loop(rig(), StaticLawController(_Pd()), rate_hz=None, delay=333e-6)
    with pytest.raises(ValueError, match="saturation"):
        closed_loop(rig(), StaticLawController(_Pd()), saturation=-1.0)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf"), "x"])
def test_gain_validation_names_the_gain(bad):
    with pytest.raises(ValueError, match="'kp'"):
        _Pd(kp=bad)
    with pytest.raises(ValueError, match="'K'"):
        check_gains("K", [1.0, bad if isinstance(bad, float) and not np.isfinite(bad) else float("nan")])


def test_static_law_controller_autodiff_matches_fd():
    sys = StaticLawController(_Pd(0.7, 0.02))
    J_ad, J_fd = autodiff_vs_fd(sys, {"joint_angle_reference": [0.1], "state": [0.05, 0.2, 0.04, -0.3]})
    np.testing.assert_allclose(J_ad, J_fd, atol=1e-8)
    np.testing.assert_allclose(J_ad, [[0.7, -0.7, 0, 0, -0.02]], atol=1e-12)


def test_quantizer_rounds_and_passes_derivatives():
    res = 200.0 / 4096
    np.testing.assert_allclose(quantize(np.array([0.01, 10.0, 10.03]), res) / res, [0, 205, 205])
    q = Quantizer(1, res, 0.0)
    J_ad, _ = autodiff_vs_fd(q, {"true_value": [10.0], "noise": [0.0]}, output="measured_value")
    np.testing.assert_allclose(J_ad, [[1.0, 0.0]])  # straight-through: average gain of a quantiser
    with pytest.raises(ValueError, match="resolution"):
        Quantizer(1, 0.0, 0.0)


def test_force_sensor_noise_and_resolution():
    p = ForceSensorParams(noise_std=0.1)
    d = force_sensor(p)
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.primitives import VectorLogSink
    from pydrake.systems.framework import DiagramBuilder
    b = DiagramBuilder()
    s = b.AddSystem(d)
    log = b.AddSystem(VectorLogSink(1, publish_period=p.sample_period))
    b.Connect(s.get_output_port(0), log.get_input_port())
    b.ExportInput(s.get_input_port(0), "f")
    dd = b.Build()
    ctx = dd.CreateDefaultContext()
    dd.GetInputPort("f").FixValue(ctx, [30.0])
    Simulator(dd, ctx).AdvanceTo(1.0)
    y = log.FindLog(ctx).data()[0]
    res = p.full_scale / 2 ** p.bits
    np.testing.assert_allclose(y / res, np.round(y / res), atol=1e-9)  # on the 12-bit grid
    sigma = math.sqrt(0.1 ** 2 + res ** 2 / 12)          # white noise + uniform quantisation error
    # the noise (0.1 N > 2 LSB) dithers the quantiser: the mean is unbiased, within 5 standard errors
    assert abs(np.mean(y) - 30.0) < 5.0 * sigma / math.sqrt(y.size)
    # the sample standard deviation of n draws has relative standard error 1 / sqrt(2 (n - 1)): 5 of them
    assert np.std(y) == pytest.approx(sigma, rel=5.0 / math.sqrt(2 * (y.size - 1)))


def test_step_metrics_on_second_order_closed_form():
    zeta, wn = 0.4, 50.0
    t = np.linspace(0, 1.0, 20001)
    wd = wn * math.sqrt(1 - zeta ** 2)
    y = 1 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta ** 2) * np.sin(wd * t))
    m = step_metrics(t, 2.0 + 3.0 * y, 2.0, 5.0)
    os_exact = math.exp(-math.pi * zeta / math.sqrt(1 - zeta ** 2))
    assert m["overshoot"] == pytest.approx(100 * os_exact, rel=1e-3)
    assert m["damping_ratio"] == pytest.approx(zeta, rel=1e-3)
    assert abs(m["steady_state_error"]) < 1e-6
    # 2 % settling of an under-damped 2nd-order system lies below the envelope bound -ln(0.02 sqrt(1-z^2))/(z wn)
    assert 0 < m["settling_time"] <= -math.log(0.02 * math.sqrt(1 - zeta ** 2)) / (zeta * wn)


def test_damping_ratio_is_nan_when_the_fit_hits_a_bound():
    """A first-order step (no 2nd-order behaviour) drives the fitted xi to its upper bound 3: reported NaN;
    a true 2nd-order step with xi = 0.4 is recovered."""
    t = np.linspace(0, 0.5, 2001)
    m = step_metrics(t, 1.0 - np.exp(-t / 0.02), 0.0, 1.0, fit=True)
    assert math.isnan(m["damping_ratio"])
    zeta, wn = 0.4, 60.0
    wd = wn * math.sqrt(1 - zeta ** 2)
    y = 1 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta ** 2) * np.sin(wd * t))
    assert step_metrics(t, y, 0.0, 1.0, fit=True)["damping_ratio"] == pytest.approx(zeta, rel=1e-3)


def test_closed_loop_twice_on_one_rig_asks_for_a_fresh_rig():
    rig = linear_flexible_joint_rig()
    closed_loop(rig, StaticLawController(_Pd()))
    with pytest.raises(ValueError, match="fresh rig"):
        closed_loop(rig, StaticLawController(_Pd()))


def test_sine_metrics_and_gain_diagram_on_known_filter():
    from scipy import signal
    t = np.arange(0, 4.0, 1e-3)
    r = np.sin(2 * np.pi * 3.0 * t)
    y = 0.5 * np.sin(2 * np.pi * 3.0 * t - math.radians(30))
    m = sine_metrics(t, r, y, 3.0)
    assert m["gain"] == pytest.approx(0.5, rel=1e-6) and m["phase_deg"] == pytest.approx(-30.0, abs=1e-4)
    # chirp through a first-order low-pass at 10 Hz: |H| = 1 / sqrt(1 + (f/10)^2)
    t = np.arange(0, 20.0, 1e-3)
    r = signal.chirp(t, 1.0, 20.0, 40.0)
    _, y, _ = signal.lsim(([2 * np.pi * 10], [1, 2 * np.pi * 10]), r, t)
    f, g = gain_diagram(t, r, y, 2.0, 35.0)
    np.testing.assert_allclose(g, 1 / np.sqrt(1 + (f / 10) ** 2), rtol=0.05)


def test_disturbance_stiffness_matches_closed_form():
    """Stiffness from the simulated torque step = the same metric on the loop's exact response: the linear closed
    loop ``x' = (A - B K) x + E tau`` after a load step at ``t_d`` is ``x(t) = (A - BK)^-1 (e^{(A - BK)(t - t_d)} - I)
    E tau`` (matrix exponential), to the integration's error (measured 7e-11 relative); its steady state
    ``-(A - BK)^-1 E tau`` gives ``tau / q_ss = kp`` exactly (motor torque = spring torque at rest).  The 1.5 s window
    leaves the slowest mode (-2.85 1/s) in the metric: 0.4989 against 0.5."""
    from scipy.linalg import expm

    from awiwi_drake.control.compare.metrics import disturbance_metrics
    kp, kd = 0.5, 0.01
    loop = closed_loop(linear_flexible_joint_rig(), StaticLawController(_Pd(kp, kd)), rate_hz=None)
    p = compare_test_params("flexible-joint", step_duration=1.5, settle_time=0.0)
    run, m = run_test(loop, "disturbance", params=p)
    A, B, E = flexible_joint_matrices()
    Acl = A - B @ np.array([[kp, 0, 0, kd]])
    tau, td = p.disturbance_torque, p.step_delay
    lam, V = np.linalg.eig(Acl)                           # e^{Acl s} = V e^{lam s} V^-1 (distinct poles)
    row = np.linalg.solve(Acl.T, np.eye(4)[0]) @ V        # q = e_0^T Acl^-1 (e^{Acl s} - I) E tau
    w = np.linalg.solve(V, E[:, 0] * tau)
    s_ = np.maximum(run.t - td, 0.0)[:, None]
    exact = np.where(run.t < td, 0.0, (np.exp(lam * s_) @ (row * w)).real
                     - np.linalg.solve(Acl, E[:, 0] * tau)[0]) + p.initial_reference
    np.testing.assert_allclose(exact[-1] - p.initial_reference, np.linalg.solve(Acl, (expm(Acl * (run.t[-1] - td))
                               - np.eye(4)) @ E[:, 0] * tau)[0], rtol=1e-9)          # = the matrix exponential
    want = disturbance_metrics(run.t, exact, p.initial_reference, td, tau)["stiffness"]
    assert m.stiffness == pytest.approx(want, rel=1e-6)
    assert tau / np.linalg.solve(Acl, -E[:, 0] * tau)[0] == pytest.approx(kp, rel=1e-12)


def test_registry_errors_and_names():
    assert {"tendon-pd", "tendon-scheduled", "tendon-sdre"} <= set(controller_names("tendon-rig"))
    assert {"pole-placement", "lqr", "sdre"} <= set(controller_names("flexible-joint"))
    with pytest.raises(ValueError, match="unknown controller 'nope'"):
        get_entry("nope")
    with pytest.raises(ValueError, match="does not fit rig 'flexible-joint'"):
        get_entry("tendon-pd", "flexible-joint")
    with pytest.raises(ValueError, match="already registered"):
        register_controller("lqr", lambda rig: None, rigs=("joint-rig",), description="dup")
    with pytest.raises(ValueError, match="unknown rig"):
        controller_names("gripper")
    for alias in ("joint", "joint_rig", "antagonistic_joint", "flexible"):     # one spelling per rig
        with pytest.raises(ValueError, match="unknown rig"):
            controller_names(alias)


def test_each_rig_has_one_name_in_api_cli_and_registry():
    from awiwi_drake.control.registry import RIG_NAMES, rig_kind
    from awiwi_drake.diagrams import TARGETS, build_target
    assert sorted(TARGETS) == sorted(RIG_NAMES)
    for name in ("tendon-rig", "flexible-joint", "joint-rig", "finger-index"):
        rig = build_target(name)
        assert rig.name == name and rig_kind(rig) == ("finger" if name.startswith("finger") else name)


def test_continuous_loop_on_a_rig_with_direct_feedthrough_gives_clear_error():
    with pytest.raises(ValueError, match="algebraic loop.*direct feedthrough.*sampled controller"):
        closed_loop(linear_flexible_joint_rig(feedthrough=1e-3), StaticLawController(_Pd()), rate_hz=None)


def test_saturation_and_slack_are_reported():
    """Joint rig (3 Nm amplifier limit, tension-only tendons, 20 N pretension)."""
    from awiwi_drake.control.impedance import impedance_controller
    from awiwi_drake.rigs import joint_rig
    rig = joint_rig()
    loop = closed_loop(rig, impedance_controller(rig, mode="pd"), rate_hz=3000.0)
    _, m = run_test(loop, "step", params=compare_test_params(rig, step_size=1.0, step_duration=0.1, settle_time=0.0))
    # the command exceeds the amplifier limit; the torque applied to the motors is clipped at it
    assert m.peak_command > rig.torque_limit and 0.1 < m.saturated_fraction < 1.0
    assert m.peak_input == pytest.approx(rig.torque_limit, rel=1e-9)
    assert m.slack_fraction == 0.0  # antagonistic motors keep the pretension
    # 0.5 Nm on the link needs 31 N of force difference: one tendon (20 N pretension) goes slack
    loop = closed_loop(joint_rig(), impedance_controller(joint_rig(), mode="two-time-scale"),
                       rate_hz=3000.0)
    _, m = run_test(loop, "disturbance", params=compare_test_params(rig, disturbance_torque=0.5, step_duration=0.1,
                                                                      settle_time=0.0))
    assert m.slack_fraction > 0.1 and m.status == "flagged" and "slack" in m.flags


def test_failed_runs_are_flagged_in_csv_and_markdown(tmp_path):
    """Pole placement (Table 12.1 design) on the antagonistic joint rig finishes but fails: command far beyond
    the 3 Nm limit, tendons slack, no settling, and the link moves with the load (negative stiffness)."""
    import csv
    import warnings
    from awiwi_drake.control.compare import compare_controllers
    from awiwi_drake.rigs import joint_rig
    p = compare_test_params("joint-rig", step_duration=0.15, settle_time=0.05)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the place_poles convergence warning is handled, not leaked
        res = compare_controllers(joint_rig, ["pole-placement"],
                                  tests=["step", "disturbance"], params=p)
    step, dist = res.table.get("pole-placement", "step"), res.table.get("pole-placement", "disturbance")
    assert step.saturated_fraction > 0.5 and step.slack_fraction > 0.1 and math.isnan(step.settling_time)
    assert step.status == "flagged" and all(k in step.flags for k in ("saturated", "slack", "not settled"))
    assert dist.stiffness < 0 and dist.status == "flagged" and "negative stiffness" in dist.flags
    rows = list(csv.DictReader(res.table.to_csv(tmp_path / "m.csv").open()))
    assert [r["status"] for r in rows] == ["flagged", "flagged"] and "not settled" in rows[0]["flags"]
    assert "| flagged: saturated" in res.table.to_markdown()


def test_plain_diagram_controller_of_a_sampled_rig_is_copied_flat_unless_its_leaves_cannot_be():
    """``closed_loop`` copies a plain-``Diagram`` controller of a sampled rig into the loop as its leaves (Clone, so
    scalar conversion); a user's diagram holding a Python ``LeafSystem`` without scalar conversion is kept whole as
    the sub-diagram ``"controller"`` (it used to raise ``System::Clone(): ... does not support Cloning``), and both
    loops give the same trajectory: the joint rig's motor PD u = -kd omega, as Drake's Simulator runs it."""
    import dataclasses
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder, LeafSystem
    from pydrake.systems.primitives import MatrixGain
    from awiwi_drake.rigs import joint_rig
    kd = 0.02

    class _Damper(LeafSystem):       # a user's leaf: no TemplateSystem, no scalar conversion
        def __init__(self):
            super().__init__()
            w = self.DeclareVectorInputPort("motor_velocity", 2)
            self.DeclareVectorOutputPort("motor_torque", 2, lambda c, o: o.SetFromVector(-kd * w.Eval(c)))

    finals = {}
    for leaf in (_Damper(), MatrixGain(-kd * np.eye(2))):
        b = DiagramBuilder()
        s = b.AddSystem(leaf)
        b.ExportInput(s.get_input_port(0), "motor_velocity")
        b.ExportOutput(s.get_output_port(0), "motor_torque")
        rig = joint_rig()
        loop = closed_loop(rig, b.Build(), rate_hz=3000.0)
        assert loop.sampled_rig
        ctrl = loop.diagram.GetSubsystemByName("controller")
        assert (type(ctrl).__name__ == "Diagram") == isinstance(leaf, _Damper), type(ctrl).__name__
        op = rig.operating_point()
        x0 = np.array(op.state, float)
        w = [i for i, nm in enumerate(rig.state_names) if nm.startswith("motor_velocity")]
        x0[w] = [3.0, -2.0]                                     # motor velocities [rad/s]: the damper acts
        sim = Simulator(loop.diagram, loop.create_context(dataclasses.replace(op, state=x0)))
        sim.AdvanceTo(0.01)
        finals[type(leaf).__name__] = loop.diagram.GetOutputPort("state").Eval(sim.get_context()).copy()
    user, flat = finals.values()
    np.testing.assert_allclose(user, flat, rtol=1e-12, atol=1e-12)
    assert np.all(np.abs(user[w]) < [3.0, 2.0])                 # damped


def test_a_factory_error_inside_is_not_reported_as_a_missing_option():
    """``make_controller`` turns only a keyword the user gave into "has no option"; a TypeError raised inside the
    factory (here a bad keyword of an inner call) reaches the user as itself."""
    from awiwi_drake.control import registry
    from awiwi_drake.control.registry import make_controller, register_controller

    def inner(**_):
        raise TypeError("inner() got an unexpected keyword argument 'colour'")

    def factory(rig, size=1.0):
        return inner(colour=size)

    register_controller("test-inner-typeerror", factory, rigs=("tendon-rig",), description="test only")
    try:
        with pytest.raises(TypeError, match="unexpected keyword argument 'colour'"):
            make_controller("test-inner-typeerror", "tendon-rig", size=2.0)
        with pytest.raises(ValueError, match="has no option 'shade'"):
            make_controller("test-inner-typeerror", "tendon-rig", shade=2.0)
    finally:
        registry._REGISTRY.pop("test-inner-typeerror", None)
