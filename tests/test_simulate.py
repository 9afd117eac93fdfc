"""The one ``simulate``: schedules against closed forms, modes, monitors, progress, results save/load/plot."""

import math

import numpy as np
import pytest
from pydrake.autodiffutils import AutoDiffXd
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import AffineSystem, Integrator, ZeroOrderHold

from awiwi_drake.analysis import (
    rig_monitors, Chirp, PerEntry, Ramp, Samples, SimulationDivergedError, SimulationError, SimulationResult, Sine, Step, simulate)
from awiwi_drake.analysis.schedules import Constant, InputSchedule_, as_schedule
from awiwi_drake.analysis.simulate import control_period
from awiwi_drake.rigs import joint_rig


def _first_order(a=5.0, b=2.0):
    """xdot = -a x + b u, y = x."""
    sys = AffineSystem(A=[[-a]], B=[[b]], f0=[0.0], C=[[1.0]], D=[[0.0]], y0=[0.0])
    sys.set_name("first_order")
    return sys


def _integrator(n=1):
    sys = Integrator(n)
    sys.set_name("integrator")
    return sys


def test_step_response_of_a_first_order_system_matches_the_closed_form():
    a, b, u1, t0 = 5.0, 2.0, 3.0, 0.1
    sys = _first_order(a, b)
    res = simulate(sys, None, 1.0, inputs={"u0": Step(t0, u1)}, log={"x": sys.get_output_port()},
                   accuracy=1e-9, max_step=1e-3)
    t = res.t
    exact = np.where(t >= t0, b * u1 / a * (1 - np.exp(-a * (t - t0))), 0.0)
    np.testing.assert_allclose(res["x"][:, 0], exact, atol=2e-6)
    assert res.info["mode"] == "error_controlled"


def test_constant_inputs_integrate_to_the_closed_form_and_are_constant_schedules():
    """A number, a vector or a PerEntry of Constants is constant in time (Drake's C++ ConstantVectorSource feeds
    it: no Python callback per step); anything with a step or a slope is not.  x = b u / a (1 - e^(-a t))."""
    a, b, u = 5.0, 2.0, 3.0
    sys = _first_order(a, b)
    for given in (u, [u], PerEntry([Constant(u)])):
        res = simulate(sys, None, 1.0, inputs={"u0": given}, log={"x": sys.get_output_port()},
                       accuracy=1e-9, max_step=1e-3)
        np.testing.assert_allclose(res["x"][:, 0], b * u / a * (1 - np.exp(-a * res.t)), atol=2e-6)
    assert as_schedule([1.0, 2.0]).constant().tolist() == [1.0, 2.0] and Constant(2.5).constant() == 2.5
    assert Step(0.1, 1.0).constant() is None and PerEntry([Constant(1.0), Step(0.1, 1.0)]).constant() is None
    assert (Constant(1.0) + Constant(2.0)).constant() is None   # a sum is evaluated, not folded
    with pytest.raises(ValueError, match="input 'u0'"):
        simulate(sys, None, 0.1, inputs={"u0": [1.0, 2.0]})


def test_ramp_sine_and_chirp_integrate_to_their_closed_forms():
    T = 0.8
    w = 2 * math.pi * 4.0
    cases = [
        (Ramp(0.2, 0.6, 1.0, 3.0), 0.2 * 1.0 + 0.4 * (1.0 + 3.0) / 2 + 0.2 * 3.0),   # areas of the pieces
        (Sine(1.5, 4.0, phase=0.3, offset=0.5), 0.5 * T + 1.5 / w * (math.cos(0.3) - math.cos(w * T + 0.3))),
    ]
    for sched, integral in cases:
        res = simulate(_integrator(), None, T, inputs={"u0": sched}, accuracy=1e-10, max_step=1e-3)
        assert res.final_state[0] == pytest.approx(integral, abs=1e-7), sched
    # chirp: integral of sin(2 pi (f0 t + k t^2 / 2)) by a fine trapezoid on the schedule's own closed form
    ch = Chirp(2.0, 1.0, 9.0, 0.7, start=0.05)
    tt = np.linspace(0.0, T, 200001)
    tau = np.clip(tt - 0.05, 0, None)
    ref = np.where((tt >= 0.05) & (tt <= 0.75),
                   2.0 * np.sin(2 * np.pi * (1.0 * tau + 0.5 * (8.0 / 0.7) * tau ** 2)), 0.0)
    res = simulate(_integrator(), None, T, inputs={"u0": ch}, accuracy=1e-10, max_step=1e-3)
    assert res.final_state[0] == pytest.approx(np.trapezoid(ref, tt), abs=1e-6)


def test_samples_and_per_entry_schedules():
    s = Samples([0.0, 0.5], [[1.0, -1.0], [2.0, -2.0]], hold="zoh")
    res = simulate(_integrator(2), None, 1.0, inputs={"u0": s}, accuracy=1e-10)
    np.testing.assert_allclose(res.final_state, [0.5 * 1 + 0.5 * 2, -(0.5 * 1 + 0.5 * 2)], atol=1e-8)
    lin = Samples([0.0, 1.0], [0.0, 2.0], hold="linear")  # u = 2 t -> x = t^2
    res = simulate(_integrator(2), None, 1.0, inputs={"u0": PerEntry([lin, 3.0])}, accuracy=1e-10)
    np.testing.assert_allclose(res.final_state, [1.0, 3.0], atol=1e-8)
    with pytest.raises(ValueError, match="strictly increasing"):
        Samples([0.0, 0.0], [1.0, 2.0])
    with pytest.raises(ValueError, match="input .u0..*3 entries but the port has 2"):
        simulate(_integrator(2), None, 1.0, inputs={"u0": PerEntry([1.0, 2.0, 3.0])})


def test_input_schedule_converts_to_autodiff_and_its_time_derivative_is_the_signal_slope():
    sched = Ramp(0.0, 2.0, 1.0, 5.0) + Sine(0.5, 3.0)
    src = InputSchedule_[float](sched, 2)
    ad = src.ToAutoDiffXd()
    ctx = ad.CreateDefaultContext()
    t = 0.37
    ctx.SetTime(AutoDiffXd(t, [1.0]))
    y = ad.get_output_port(0).Eval(ctx)
    slope = 4.0 / 2.0 + 0.5 * 2 * math.pi * 3.0 * math.cos(2 * math.pi * 3.0 * t)
    h = 1e-6
    fd = (sched.value(t + h) - sched.value(t - h)) / (2 * h)
    for yi in y:
        assert yi.derivatives()[0] == pytest.approx(slope, rel=1e-12)
        assert yi.derivatives()[0] == pytest.approx(fd, rel=1e-7)


def _sampled_loop(period=1e-3):
    """A plant xdot = -x + u under a sampled proportional controller u = 4 (r - x) held for ``period``."""
    b = DiagramBuilder()
    plant = b.AddNamedSystem("plant", AffineSystem(A=[[-1.0]], B=[[1.0]], f0=[0.0], C=[[1.0]], D=[[0.0]], y0=[0.0]))
    ctrl = b.AddNamedSystem("ctrl", AffineSystem(A=np.zeros((0, 0)), B=np.zeros((0, 2)), f0=np.zeros(0),
                                                 C=np.zeros((1, 0)), D=[[4.0, -4.0]], y0=[0.0]))
    hold = b.AddNamedSystem("hold", ZeroOrderHold(period, 1))
    from pydrake.systems.primitives import Multiplexer
    mux = b.AddNamedSystem("mux", Multiplexer([1, 1]))
    b.ExportInput(mux.get_input_port(0), "x_reference")
    b.Connect(plant.get_output_port(), mux.get_input_port(1))
    b.Connect(mux.get_output_port(), ctrl.get_input_port())
    b.Connect(ctrl.get_output_port(), hold.get_input_port())
    b.Connect(hold.get_output_port(), plant.get_input_port())
    b.ExportOutput(plant.get_output_port(), "x")
    b.ExportOutput(hold.get_output_port(), "motor_torque")
    d = b.Build()
    d.set_name("sampled_loop")
    return d


def test_two_rate_loops_step_at_the_common_period_and_match_the_sampled_data_closed_form():
    """A 6 kHz law reading a 3 kHz sensor hold (the hand's chain and estimator): the fixed step is 1/6000 s."""
    from pydrake.systems.primitives import Multiplexer
    b = DiagramBuilder()
    plant = b.AddNamedSystem("plant", AffineSystem(A=[[-1.0]], B=[[1.0]], f0=[0.0], C=[[1.0]], D=[[0.0]], y0=[0.0]))
    sensor = b.AddNamedSystem("sensor", ZeroOrderHold(1.0 / 3000, 1))
    ctrl = b.AddNamedSystem("ctrl", AffineSystem(A=np.zeros((0, 0)), B=np.zeros((0, 2)), f0=np.zeros(0),
                                                 C=np.zeros((1, 0)), D=[[4.0, -4.0]], y0=[0.0]))
    hold = b.AddNamedSystem("hold", ZeroOrderHold(1.0 / 6000, 1))
    mux = b.AddNamedSystem("mux", Multiplexer([1, 1]))
    b.ExportInput(mux.get_input_port(0), "x_reference")
    b.Connect(plant.get_output_port(), sensor.get_input_port())
    b.Connect(sensor.get_output_port(), mux.get_input_port(1))
    b.Connect(mux.get_output_port(), ctrl.get_input_port())
    b.Connect(ctrl.get_output_port(), hold.get_input_port())
    b.Connect(hold.get_output_port(), plant.get_input_port())
    b.ExportOutput(plant.get_output_port(), "x")
    d = b.Build()
    assert d.GetUniquePeriodicDiscreteUpdateAttribute() is None   # Drake sees no single rate
    h = 1.0 / 6000
    assert control_period(d) == h
    t_step = 0.0051                                               # between ticks 30 and 31
    res = simulate(d, None, 3000 * h, inputs={"x_reference": Step(t_step, 1.0)}, log=("x",))
    assert res.info["mode"] == "fixed_step" and res.info["step"] == h
    np.testing.assert_allclose(np.diff(res.t), h, rtol=1e-6)
    # sampled-data closed form: at tick n both holds update from the pre-update values,
    # y <- x(t_n) on even n (3 kHz), u <- 4 (r(t_n) - y_old); then x(t_{n+1}) = e^-h x + (1 - e^-h) u
    x, y, ref = 0.0, 0.0, []
    for n in range(len(res.t)):
        ref.append(x)
        u = 4.0 * ((1.0 if n * h > t_step else 0.0) - y)
        y = x if n % 2 == 0 else y
        x = math.exp(-h) * x + (1 - math.exp(-h)) * u
    assert abs(ref[-1]) > 0.5                                     # the step has been followed
    np.testing.assert_allclose(res["x"][:, 0], ref, atol=1e-10)
    # a rate that is not commensurate leaves the common period undefined: error control
    b2 = DiagramBuilder()
    for p in (1e-3, math.pi * 1e-3):
        b2.ExportInput(b2.AddSystem(ZeroOrderHold(p, 1)).get_input_port())
    assert control_period(b2.Build()) is None


def test_sampled_loops_default_to_fixed_steps_at_the_control_period_and_match_error_control():
    d = _sampled_loop(1e-3)
    assert control_period(d) == pytest.approx(1e-3)
    fixed = simulate(d, None, 0.5, inputs={"x_reference": Step(0.05, 1.0)}, log=("x", "motor_torque"))
    assert fixed.info["mode"] == "fixed_step" and fixed.info["step"] == pytest.approx(1e-3)
    np.testing.assert_allclose(np.diff(fixed.t), 1e-3, rtol=1e-9)
    exact = simulate(d, None, 0.5, inputs={"x_reference": Step(0.05, 1.0)}, log=("x",), mode="error_controlled",
                     accuracy=1e-10, max_step=1e-4)
    xe = np.interp(fixed.t, exact.t, exact["x"][:, 0])
    # the held input is piecewise constant on the steps: RK3 is exact to O(h^4) per step
    assert np.max(np.abs(fixed["x"][:, 0] - xe)) < 1e-9
    # exact sampled-data solution: x[k+1] = e^-h x[k] + (1 - e^-h) u[k], u[k] = 4 (r[k] - x[k])
    h, xk, ref = 1e-3, 0.0, []
    for k in range(len(fixed.t)):
        ref.append(xk)
        rk = 1.0 if k * h >= 0.05 - 1e-12 else 0.0
        xk = math.exp(-h) * xk + (1 - math.exp(-h)) * 4.0 * (rk - xk)
    np.testing.assert_allclose(fixed["x"][:, 0], ref, atol=1e-9)
    with pytest.raises(ValueError, match="divisor"):
        simulate(d, None, 0.1, inputs={"x_reference": 0.0}, step=3e-4)


def test_progress_is_reported_up_to_the_duration_and_chunks_do_not_change_the_run():
    calls = []
    d = _sampled_loop()
    a = simulate(d, None, 0.3, inputs={"x_reference": Sine(1.0, 5.0)}, log=("x",), progress=lambda t, T: calls.append((t, T)))
    assert calls[-1] == (pytest.approx(0.3), pytest.approx(0.3)) and len(calls) > 5
    assert all(t1 > t0 for (t0, _), (t1, _) in zip(calls, calls[1:]))
    b = simulate(d, None, 0.3, inputs={"x_reference": Sine(1.0, 5.0)}, log=("x",))
    np.testing.assert_array_equal(a["x"], b["x"])


def test_divergence_in_fixed_step_mode_and_bad_times_raise_the_package_errors():
    sys = AffineSystem(A=[[300.0]], B=[[0.0]], f0=[0.0], C=[[1.0]], D=[[0.0]], y0=[0.0])
    ctx = sys.CreateDefaultContext()
    ctx.SetContinuousState([1.0])
    with pytest.raises(SimulationDivergedError, match=r"diverged at t = .*state\[0\]"):
        simulate(sys, ctx, 2.0, inputs={"u0": 0.0}, mode="fixed_step", step=1e-2)
    ctx = sys.CreateDefaultContext()
    ctx.SetTime(1.0)
    with pytest.raises(ValueError, match="t_final = 0.5 s must be after the start time 1.0 s"):
        simulate(sys, ctx, 0.5, inputs={"u0": 0.0})
    with pytest.raises(ValueError, match="t_final = inf"):
        simulate(sys, None, math.inf, inputs={"u0": 0.0})
    with pytest.raises(ValueError, match="no input port 'torque'"):
        simulate(sys, None, 1.0, inputs={"torque": 0.0})
    with pytest.raises(ValueError, match="input port 'u0' .* neither fixed"):
        simulate(sys, None, 1.0)
    assert issubclass(SimulationDivergedError, SimulationError)


def test_the_context_is_advanced_and_the_diagram_can_be_simulated_again():
    rig = joint_rig()
    op = rig.operating_point(pretension=20.0)
    ctx = rig.context(op)
    r1 = simulate(rig, ctx, 0.01, inputs={"motor_torque": op.motor_torque + [0.3, -0.3]})
    assert ctx.get_time() == pytest.approx(0.01)
    r2 = simulate(rig, ctx, 0.02, inputs={"motor_torque": op.motor_torque + [0.3, -0.3]})
    assert r2.t[0] == pytest.approx(0.01)
    np.testing.assert_allclose(r2["state"][0], r1["state"][-1], rtol=0, atol=0)
    assert r1.labels["state"] == list(rig.state_names) and r1.units["state"][0] == "rad"
    assert r1.units["state"][1] == "rad/s"


def test_every_state_of_every_rig_and_the_hand_has_its_unit():
    """The one state-naming scheme (rigs.base.state_names) has one unit table: every state entry of every rig and of
    the hand with all of the thesis's physics on (every finger's joints and tendons, Dahl, guide-friction and joint
    stick-slip states) has a unit, the unit of its quantity, and simulate labels a logged state with them."""
    from awiwi_drake import rigs
    from awiwi_drake.analysis.results import unit
    from awiwi_drake.hand.diagrams import hand_diagram
    from awiwi_drake.parameters.components import HysteresisParams
    from awiwi_drake.parameters.hand import HandRigParams
    from awiwi_drake.parameters.rigs import JointRigParams
    hand = hand_diagram(params=HandRigParams().with_physics(hysteresis=True, guide_friction=True, joint_friction=True))
    link = [getattr(rigs, f)() for f in rigs.__all__ if f.endswith("_rig")]
    p = JointRigParams()
    link.append(rigs.joint_rig(params=p.replace(spring=p.spring.replace(hysteresis=HysteresisParams(enabled=True)))))
    names = [n for r in link + [hand] for n in r.state_names]
    assert {n.split("[")[0] for n in hand.state_names} == {
        "joint_angle", "joint_velocity", "motor_angle", "motor_velocity", "hysteresis_force", "guide_friction_force",
        "joint_friction_torque"}                         # the hand carries every kind of state the scheme names
    assert [n for n in names if unit(n) == "-"] == []
    by_kind = {n.split("[")[0]: unit(n) for n in names}
    assert by_kind == {"joint_angle": "rad", "joint_velocity": "rad/s", "motor_angle": "rad", "motor_velocity": "rad/s",
                       "hysteresis_force": "N", "guide_friction_force": "N", "joint_friction_torque": "Nm"}
    rig = link[-1]
    res = simulate(rig, rig.context(rig.operating_point(pretension=20.0)), 1e-3)
    assert res.labels["state"] == list(rig.state_names) and res.units["state"] == [unit(n) for n in rig.state_names]
    assert res.units["state"][-1] == "N"                 # hysteresis_force[1]


def test_results_save_load_and_plot_with_units_and_legends(tmp_path):
    rig = joint_rig()
    op = rig.operating_point(pretension=20.0)
    limit = rig.torque_limit
    res = simulate(rig, rig.context(op), 0.02,
                   inputs={"motor_torque": PerEntry([Step(0.005, limit + 0.5, before=op.motor_torque[0]),
                                                     op.motor_torque[1]])},
                   log=("joint_angle", "tendon_force", "motor_torque"), monitors=rig_monitors(rig))
    sat = res.events_of("actuator_saturation")
    assert [e.channel for e in sat] == ["motor_torque[0]"] and sat[0].t_start == pytest.approx(0.005, abs=2e-3)
    assert sat[0].extreme == pytest.approx(limit + 0.5)
    for ext in ("npz", "csv"):
        path = res.save(tmp_path / f"run.{ext}")
        back = SimulationResult.load(path)
        np.testing.assert_allclose(back.t, res.t)
        for k in res.signals:
            np.testing.assert_allclose(back[k], res[k], rtol=1e-15 if ext == "npz" else 1e-12)
        assert back.units == res.units and back.info["mode"] == res.info["mode"]
        assert back.limits == res.limits and back.final_sampled_state is None
    assert res.units["tendon_force"] == "N" and res.units["motor_torque"] == "Nm"
    assert sorted(v for _, v in res.limits["motor_torque"]) == [-limit, limit]
    fig, axes = back.plot()             # the loaded result draws the monitors' limits and the events
    for ax in axes:
        assert "[" in ax.get_ylabel() and ax.get_legend() is not None
        assert len(ax.get_legend().get_texts()) >= 1
    torque_ax = next(a for a in axes if a.get_ylabel() == "motor_torque [Nm]")
    texts = [t.get_text() for t in torque_ax.get_legend().get_texts()]
    assert any("torque limit" in t for t in texts) and "actuator saturation (event)" in texts
    assert {round(ln.get_ydata()[0], 9) for ln in torque_ax.get_lines() if ln.get_linestyle() == "--"} == {limit, -limit}
    assert axes[-1].get_xlabel() == "time [s]"
    with pytest.raises(ValueError, match="must end in .npz or .csv"):
        res.save(tmp_path / "run.txt")
    with pytest.raises(ValueError, match="is not a file"):
        SimulationResult.load(tmp_path / "missing.npz")


def _divergence_error_misuses(folders) -> list:
    """``file:line: what`` for every place under ``folders`` that raises ``FloatingPointError``, raises a bare
    ``RuntimeError`` whose message speaks of divergence, or re-wraps a divergence: an ``except`` that catches
    ``SimulationDivergedError``/``SimulationError``/``PHYSICAL_FAILURES`` (or ``RuntimeError``/``Exception`` around a
    ``simulate``/``AdvanceTo`` call) and raises anything but that exception or a ``SimulationDivergedError``."""
    import ast
    import pathlib

    def names(node):
        return {n.id if isinstance(n, ast.Name) else n.attr for n in ast.walk(node)
                if isinstance(n, (ast.Name, ast.Attribute))}

    def raised(node):      # the raised class's name, or None for a bare raise / a raised variable
        exc = node.exc.func if isinstance(node.exc, ast.Call) else node.exc
        return None if exc is None else (exc.id if isinstance(exc, ast.Name) else getattr(exc, "attr", None))

    def text(node):
        return " ".join(str(c.value) for c in ast.walk(node) if isinstance(c, ast.Constant))

    found = []
    for path in sorted(p for folder in folders for p in pathlib.Path(folder).rglob("*.py")):
        src = path.read_text()
        if not any(k in src for k in ("FloatingPointError", "iverg", "Simulation", "PHYSICAL_FAILURES", "AdvanceTo",
                                      "simulate")):
            continue        # none of what the scan looks for: not parsed
        tree = ast.parse(src)
        where = f"{path.parent.name}/{path.name}"
        for node in ast.walk(tree):
            if isinstance(node, ast.Raise) and node.exc is not None:
                kind = raised(node)
                if kind == "FloatingPointError" or (kind == "RuntimeError" and "diverg" in text(node.exc).lower()):
                    found.append(f"{where}:{node.lineno}: raise {kind}")
            if not isinstance(node, ast.Try):
                continue
            runs = {"simulate", "AdvanceTo"} & names(ast.Module(body=node.body, type_ignores=[]))
            passed_on = False       # an earlier handler of this try already took the divergence
            for h in node.handlers:
                caught = names(h.type) if h.type is not None else {"BaseException"}
                ours = caught & {"SimulationDivergedError", "SimulationError", "PHYSICAL_FAILURES"}
                if not (ours or (runs and not passed_on and caught & {"RuntimeError", "Exception", "BaseException"})):
                    continue
                passed_on = passed_on or bool(ours)
                for r in (n for stmt in h.body for n in ast.walk(stmt) if isinstance(n, ast.Raise)):
                    kind = raised(r)
                    if kind is not None and kind != "SimulationDivergedError" and not (
                            isinstance(r.exc, ast.Name) and r.exc.id == h.name):
                        found.append(f"{where}:{r.lineno}: a caught divergence re-raised as {kind}")
    return found


def test_one_simulation_loop_and_one_divergence_error(tmp_path):
    """Architecture (issue 9): the package drives Drake's Simulator in one place (plus the batched
    discrepancy replay) and defines one SimulationDivergedError, which nothing re-wraps (the scan is shown to
    find each misuse in a planted file first)."""
    import pathlib

    import awiwi_drake

    pkg = pathlib.Path(awiwi_drake.__file__).parent
    allowed = {"analysis/simulate.py", "discrepancy/replay.py"}
    loops = sorted(p.relative_to(pkg).as_posix() for p in pkg.rglob("*.py")
                   if "Simulator(" in p.read_text() and p.relative_to(pkg).as_posix() not in allowed)
    assert loops == [], f"Simulator driven outside analysis.simulate: {loops}"
    errors = sorted(p.relative_to(pkg).as_posix() for p in pkg.rglob("*.py")
                    if "class SimulationDivergedError" in p.read_text())
    assert errors == ["analysis/simulate.py"]
    # ... and that one error in practice: divergence is never re-wrapped (caught and raised as another type) nor
    # raised as FloatingPointError or a bare RuntimeError, in the package or the benchmarks
    (tmp_path / "planted.py").write_text(
        "try:\n    simulate(d, c, 1.0)\nexcept SimulationDivergedError as exc:\n"
        "    raise FloatingPointError(str(exc))\n"
        "try:\n    sim.AdvanceTo(1.0)\nexcept RuntimeError as exc:\n    raise ValueError(str(exc))\n"
        "try:\n    simulate(d, c, 1.0)\nexcept SimulationDivergedError:\n    raise\nexcept RuntimeError as exc:\n"
        "    raise SimulationError(str(exc))\n"
        "raise RuntimeError('the run diverged')\nraise RuntimeError('no port')\n")
    assert sorted(_divergence_error_misuses([tmp_path])) == sorted(f"{tmp_path.name}/planted.py:{what}" for what in (
        "4: a caught divergence re-raised as FloatingPointError", "4: raise FloatingPointError",
        "8: a caught divergence re-raised as ValueError", "15: raise RuntimeError"))
    assert _divergence_error_misuses([pkg, pkg.parent / "benchmarks"]) == []
    # the benchmarks run through simulate; a raw Simulator loop only as the baselines of simulate's own cost
    import ast

    def drives_simulator(fn):
        stack = list(fn.body)
        while stack:
            node = stack.pop()
            if isinstance(node, (ast.FunctionDef, ast.Lambda)):
                continue
            if isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", None)) == "Simulator":
                return True
            stack.extend(ast.iter_child_nodes(node))
        return False
    raw = sorted(f"{b.name}:{fn.name}" for b in (pkg.parent / "benchmarks").glob("*.py")
                 for fn in ast.walk(ast.parse(b.read_text()))
                 if isinstance(fn, ast.FunctionDef) and drives_simulator(fn))
    assert raw == ["bench_rigs.py:_fixed_rk3", "bench_rigs.py:_period_us"]
    # one closed-loop builder: ClosedLoop handles come from control.closed_loop only
    handles = sorted(p.relative_to(pkg).as_posix() for p in pkg.rglob("*.py")
                     if "ClosedLoop(" in p.read_text().replace("class ClosedLoop(", ""))
    assert handles == ["control/base.py"], f"ClosedLoop built outside closed_loop: {handles}"


@pytest.mark.parametrize("which", ["joint_rig", "tendon_rig"])
def test_force_monitors_on_the_logged_state_find_what_the_port_monitors_find(which):
    """The slack and over-range monitors of the joint rig and the tendon rig compute the tendon forces
    from the logged state (numpy, once per chunk) instead of evaluating the port every step: same
    events, same extremes, and the limits still drawn on a logged tendon_force."""
    from awiwi_drake.analysis import OverrangeMonitor, SlackMonitor
    from awiwi_drake.rigs import tendon_rig
    rig = joint_rig() if which == "joint_rig" else tendon_rig()
    op = rig.operating_point(pretension=5.0) if which == "joint_rig" else rig.operating_point(tendon_force=5.0)
    # the motor(s) wind (2.5 Nm / r_m = 500 N > the 180 N range), then unwind (slack)
    u = Step(0.003, 2.5, before=op.motor_torque[0]) + Step(0.1, -5.0)
    from_state = rig_monitors(rig)
    assert [m.port_name for m in from_state if m.kind in ("tendon_slack", "spring_overrange")] == ["state", "state"]
    on_port = [SlackMonitor(rig.diagram), OverrangeMonitor(rig.diagram, rig.max_force)]
    res_a = simulate(rig, rig.context(op), 0.2, inputs={"motor_torque": u}, log=("tendon_force",),
                     monitors=from_state, mode="fixed_step", step=2e-4)
    res_b = simulate(rig, rig.context(op), 0.2, inputs={"motor_torque": u}, log=("tendon_force",),
                     monitors=on_port, mode="fixed_step", step=2e-4)
    kinds = ("tendon_slack", "spring_overrange")
    ev_a = [e.to_json() for e in res_a.events if e.kind in kinds]
    ev_b = [e.to_json() for e in res_b.events if e.kind in kinds]
    assert {e["kind"] for e in ev_b} == set(kinds)          # the run does hit both conditions
    assert [(e["kind"], e["channel"], e["t_start"], e["t_end"]) for e in ev_a] == \
        [(e["kind"], e["channel"], e["t_start"], e["t_end"]) for e in ev_b]
    np.testing.assert_allclose([e["extreme"] for e in ev_a], [e["extreme"] for e in ev_b], rtol=1e-12, atol=1e-12)
    assert res_a.limits["tendon_force"] == res_b.limits["tendon_force"]


def test_simulate_runs_a_flat_copy_of_nested_diagrams_bit_for_bit():
    """simulate copies the leaves of a nested diagram flat (analysis.add_flat): a continuous loop (the rig and the
    controller as sub-diagrams, an input fanning out to two leaves) and a sampled loop give the same samples and
    end state as Drake's Simulator on the original diagram with the same integrator, bit for bit, and the user's
    context (every leaf's state, nested ones included) is advanced to that end."""
    from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
    from pydrake.systems.framework import InputPort

    from awiwi_drake.analysis import add_flat
    from awiwi_drake.control import closed_loop
    from awiwi_drake.control.motor_position import motor_position_controller
    for sampled in (False, True):
        rig = joint_rig()
        op = rig.operating_point(pretension=20.0)
        loop = closed_loop(rig, motor_position_controller(rig), sampled_rig=sampled)
        refs = {"motor_angle_reference": op.state[2:4] + [0.05, -0.05], "tendon_force_reference": op.tendon_force}
        ctx = loop.create_context(op, references=refs)
        ref_ctx = ctx.Clone()
        res = simulate(loop.diagram, ctx, 0.02, log=("state", "motor_torque"))
        sim = Simulator(loop.diagram, ref_ctx)
        ResetIntegratorFromFlags(sim, "runge_kutta3", 1 / 3000)
        sim.get_mutable_integrator().set_fixed_step_mode(True)
        sim.Initialize()
        sim.AdvanceTo(res.t[-1])
        assert ctx.get_time() == ref_ctx.get_time()
        def state(c):
            return np.concatenate([c.get_continuous_state_vector().CopyToVector()]
                                  + [c.get_discrete_state(i).CopyToVector() for i in range(c.num_discrete_state_groups())])
        assert state(ctx).size > 6
        np.testing.assert_array_equal(state(ctx), state(ref_ctx))
        np.testing.assert_array_equal(res["state"][-1], loop.diagram.GetOutputPort("state").Eval(ref_ctx))
        assert loop.diagram.HasSubsystemNamed("rig") is not sampled      # a nested rig when continuous
    b = DiagramBuilder()          # an exported input feeding two leaves inside a sub-diagram
    inner = DiagramBuilder()
    i1, i2 = inner.AddSystem(_integrator()), inner.AddSystem(_first_order())
    i2.set_name("f")
    inner.ExportInput(i1.get_input_port(), "u")
    inner.ConnectInput("u", i2.get_input_port())
    inner.ExportOutput(i1.get_output_port(), "x")
    inner.ExportOutput(i2.get_output_port(), "y")
    sub = b.AddSystem(inner.Build())
    b.ExportInput(sub.get_input_port(0), "u")
    b.ExportOutput(sub.get_output_port(0), "x")
    b.ExportOutput(sub.get_output_port(1), "y")
    d = b.Build()
    flat = add_flat(DiagramBuilder(), d, "copy")
    assert [len(p) for p in flat.inputs] == [2] and len(flat.leaves) == 2
    assert isinstance(flat.inputs[0][0], InputPort)
    res = simulate(d, d.CreateDefaultContext(), 1.0, inputs={"u": 1.0}, log=("x", "y"), mode="error_controlled",
                   accuracy=1e-10)
    np.testing.assert_allclose(res["x"][-1], [1.0], atol=1e-9)                     # x' = 1
    np.testing.assert_allclose(res["y"][-1], [0.4 * (1 - math.exp(-5.0))], atol=1e-8)   # y' = -5 y + 2
