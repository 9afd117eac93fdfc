"""Figures explain themselves: every trace in a legend, units on every axis, limits and events drawn.

The demo figure is drawn from a real (short) simulation of the demo loop; the checks are on the
matplotlib objects, plus the physics the figure claims: the applied torque is the commanded one
clipped at the motor's torque limit.
"""

from __future__ import annotations

import re

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

UNIT = re.compile(r"\[[^\]]+\]")


def _traces(ax):
    return [ln for ln in ax.get_lines() if len(np.atleast_1d(ln.get_xdata())) > 2]


def _check_axes_explained(axes, *, need_legend=True):
    for a in axes:
        assert UNIT.search(a.get_ylabel()), f"no unit on y axis {a.get_ylabel()!r}"
        if need_legend:
            leg = a.get_legend()
            assert leg is not None, f"panel {a.get_ylabel()!r} has no legend"
            labels = {t.get_text() for t in leg.get_texts()}
            for ln in _traces(a):
                assert ln.get_label() in labels, f"trace {ln.get_label()!r} of {a.get_ylabel()!r} not in the legend"


@pytest.fixture(scope="module")
def demo_run():
    from awiwi_drake.analysis import rig_monitors, simulate
    from awiwi_drake.control.motor_position import demo_references, joint_rig_position_loop
    from awiwi_drake.parameters.rigs import DemoScenario
    from awiwi_drake.rigs.rigs import joint_rig

    rig = joint_rig()
    sc = DemoScenario(t_final=0.85, ramp_time=0.3, step_time=0.7)
    loop = joint_rig_position_loop(rig, sc)
    t_ref, refs = demo_references(rig, sc)
    ctx = loop.create_context(rig.operating_point(pretension=sc.f_start))
    res = simulate(loop.diagram, ctx, sc.t_final,
                   log=("joint_angle", "tendon_force", "motor_torque", "motor_torque_command", "applied_torque"),
                   monitors=rig_monitors(rig), max_step=1.0 / 3000)
    return rig, sc, t_ref, refs, res


def test_demo_figure_has_legends_units_limit_and_applied_torque(demo_run):
    import matplotlib.pyplot as plt

    from awiwi_drake.reproductions.demo import demo_figure

    rig, sc, t_ref, refs, res = demo_run
    limit = rig.torque_limit
    fig = demo_figure(res, t_ref, refs, sc, torque_limit=limit)
    axes = np.array(fig.axes).reshape(3, 2)
    _check_axes_explained(axes[:, 0])
    for a in axes[-1]:
        assert "[s]" in a.get_xlabel()
    labels = {t.get_text() for t in axes[2, 0].get_legend().get_texts()}
    assert {"motor 1 applied", "motor 2 applied", "motor 1 commanded", "motor 2 commanded"} <= labels
    assert any(lab.startswith("limit") for lab in labels)
    assert "actuator saturation (event)" in labels            # the shaded interval is named
    hlines = [ln.get_ydata()[0] for ln in axes[2, 0].get_lines() if np.ptp(ln.get_ydata()) == 0]
    assert limit in hlines and -limit in hlines
    # the zoom column shows the step window
    lo, hi = axes[0, 1].get_xlim()
    assert lo < sc.step_time < hi and hi - lo < 0.3
    plt.close(fig)
    # physics the figure claims: applied = commanded clipped at the limit
    cmd, app = res["motor_torque_command"], res["applied_torque"]
    assert np.max(np.abs(cmd)) > limit                       # the step saturates (why the limit is drawn)
    np.testing.assert_allclose(app, np.clip(res["motor_torque"], -limit, limit), atol=1e-9)


def test_pole_sweep_symlog_keeps_slow_poles_visible():
    import matplotlib.pyplot as plt

    from awiwi_drake.plotting import plot_poles

    poles = [np.array([-2800.0, -700 + 1500j, -700 - 1500j, -0.05, 1e-13]) * s for s in (1.0, 1.1)]
    fig, ax = plot_poles(poles, values=[10.0, 20.0], name="pretension [N]", symlog=0.01)
    assert ax.get_xscale() == "symlog"
    # -0.05 1/s lies a visible distance from the origin on the transformed axis (> 5 % of the axis width)
    tr = ax.transData.transform
    x0, x1 = tr((0.0, 0.0))[0], tr((-0.05, 0.0))[0]
    width = ax.get_window_extent().width
    assert abs(x1 - x0) > 0.05 * width
    lo, hi = ax.get_xlim()
    assert lo < -2800 and hi > 0
    plt.close(fig)
    with pytest.raises(ValueError, match="3 values for 2 pole sets"):
        plot_poles(poles, values=[1.0, 2.0, 3.0])


def test_linearisation_pole_map_shows_the_poles_on_their_damping_rays():
    """``LinearizationResult.plot()``: the s-plane map of the poles of A; a second-order system with
    wn = 40 rad/s, zeta = 0.5 puts its poles ``-20 +- 34.64j`` on the zeta = 0.5 ray
    (``Im / Re = -sqrt(1 - zeta^2) / zeta``). ``LqrResult.plot()`` adds the closed loop on the same axes."""
    import matplotlib.pyplot as plt

    from pydrake.systems.primitives import LinearSystem

    from awiwi_drake.analysis import linearize, lqr
    from awiwi_drake.rigs import flexible_joint_rig

    wn, zeta = 40.0, 0.5
    sys_ = LinearSystem(np.array([[0.0, 1.0], [-wn ** 2, -2 * zeta * wn]]), np.array([[0.0], [wn ** 2]]),
                        np.eye(2), np.zeros((2, 1)))
    ctx = sys_.CreateDefaultContext()
    sys_.get_input_port().FixValue(ctx, [0.0])
    lin = linearize(sys_, context=ctx, input=sys_.get_input_port().get_name())
    fig, ax = lin.plot()
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    pts = lines["poles"].get_xydata()
    np.testing.assert_allclose(sorted(pts[:, 1]), [-wn * np.sqrt(1 - zeta ** 2), wn * np.sqrt(1 - zeta ** 2)])
    np.testing.assert_allclose(pts[:, 0], -zeta * wn)
    ray = next(ln for lab, ln in lines.items() if lab.startswith("damping ratio"))
    assert "0.5" in ray.get_label()
    rays = [ln.get_xy2() for ln in ax.get_lines() if ln.get_color() == ray.get_color()]   # lines through 0
    assert len(rays) == 10 and all(x < 0 for x, _ in rays)
    assert any(abs(y / x + np.sqrt(1 - zeta ** 2) / zeta) < 1e-12 for x, y in rays)
    assert ax.get_ylim()[1] < 2 * wn       # the rays do not stretch the view beyond the poles
    plt.close(fig)
    design = lqr(flexible_joint_rig(), np.diag([10, 0.01, 1, 0.01]), [[1e-2]])
    fig, ax = design.plot()
    lines = {ln.get_label(): ln.get_xydata() for ln in ax.get_lines()}
    got = np.sort_complex(lines["closed loop (LQR)"] @ [1, 1j])
    np.testing.assert_allclose(got, np.sort_complex(design.closed_loop_poles), rtol=1e-12)
    np.testing.assert_allclose(np.sort_complex(lines["open loop"] @ [1, 1j]),
                               np.sort_complex(design.linearization.poles), rtol=1e-12)
    plt.close(fig)


def test_bandwidth_of_a_first_order_gain_is_its_corner_frequency():
    """-3 dB bandwidth from a linear FFT grid: log-interpolated, not the first grid point."""
    from awiwi_drake.control.compare import sweep_metrics

    f = np.arange(1.0, 70.0, 1.0)               # the chirp's 1 Hz bins
    for fc in (5.0, 7.7, 31.4):                  # corners well above the sweep start (1 Hz)
        g = 0.8 / np.abs(1 + 1j * f / fc)        # DC gain 0.8 (a loop with steady-state error)
        bw = sweep_metrics(f, g)["bandwidth_hz"]
        assert bw == pytest.approx(fc, rel=0.06), (fc, bw)
    assert np.isnan(sweep_metrics(f, np.ones_like(f))["bandwidth_hz"])   # never falls: NaN, not 69 Hz


def test_resonance_is_an_interior_peak_of_the_gain_diagram():
    """A second-order gain |w0^2 / (w0^2 - w^2 + 2 i xi w0 w)| peaks at w0 sqrt(1 - 2 xi^2) (xi < 1/sqrt 2);
    a monotone (first-order) diagram has no resonance in the sweep: NaN, not the first grid point."""
    from awiwi_drake.control.compare import sweep_metrics

    f = np.arange(2.0, 70.0, 0.25)
    f0, xi = 20.0, 0.2
    g = f0 ** 2 / np.abs(f0 ** 2 - f ** 2 + 2j * xi * f0 * f)
    m = sweep_metrics(f, g)
    assert m["resonance_hz"] == pytest.approx(f0 * np.sqrt(1 - 2 * xi ** 2), abs=0.25)
    assert m["peak_gain"] == pytest.approx(1 / (2 * xi * np.sqrt(1 - xi ** 2)), rel=1e-3)
    mono = sweep_metrics(f, 1 / np.abs(1 + 1j * f / 5.0))
    assert np.isnan(mono["resonance_hz"]) and mono["peak_gain"] == pytest.approx(1 / np.sqrt(1 + 0.16))


def test_dominant_time_constant_of_pole_placement_is_its_slowest_pole():
    """Pole placement (ch. 12) puts the closed-loop poles at xi_i omega_i: the slowest is 0.7 * 30 = 21 1/s."""
    from awiwi_drake.control.base import closed_loop
    from awiwi_drake.control.compare import dominant_time_constant
    from awiwi_drake.control.registry import get_entry
    from awiwi_drake.parameters.control import PolePlacementParams
    from awiwi_drake.rigs import flexible_joint_rig

    rig = flexible_joint_rig()
    entry = get_entry("pole-placement", rig)
    loop = closed_loop(rig, entry.factory(rig), **{**entry.loop_options, "rate_hz": None})
    p = PolePlacementParams()
    tau = dominant_time_constant(loop)
    assert tau == pytest.approx(1.0 / min(p.xi1 * p.omega1, p.xi2 * p.omega2), rel=1e-6)
    rig = flexible_joint_rig()
    sampled = closed_loop(rig, entry.factory(rig), **{**entry.loop_options, "rate_hz": 3000.0})
    assert dominant_time_constant(sampled) is None    # mixed discrete/continuous: no Linearize, no guess


def test_compare_figures_have_legends_labels_and_bandwidth(tmp_path):
    import matplotlib.pyplot as plt

    from awiwi_drake.control.compare import compare_controllers, plot_gain_diagram, plot_runs
    from awiwi_drake.control.compare import compare_test_params
    from awiwi_drake.rigs import joint_rig

    params = compare_test_params("joint-rig").replace(step_duration=0.15, sweep_duration=1.0, settle_time=0.05)
    res = compare_controllers(lambda: joint_rig(), ["pd"], tests=["step", "sweep"], params=params)
    fig, ax = plot_runs(res, "step", ylabel="link angle [rad]")
    _check_axes_explained([ax])
    assert "[s]" in ax.get_xlabel()
    plt.close(fig)
    fig, ax = plot_gain_diagram(res, unit="rad")
    _check_axes_explained([ax])
    assert ax.get_xscale() == "log" and "[Hz]" in ax.get_xlabel() and "[rad/rad]" in ax.get_ylabel()
    m = res.table.get("pd", "sweep")
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any("-3 dB" in lab for lab in labels) and np.isfinite(m.bandwidth_hz)
    plt.close(fig)
    # peak_input is the applied torque (saturated at the motor's limit), beside the command
    step = res.table.get("pd", "step")
    limit = joint_rig().torque_limit
    assert step.peak_input <= limit + 1e-9 < step.peak_command
    md = res.table.to_markdown(ref_unit="rad")
    assert "steady_state_error [rad]" in md and "[ref]" not in md and "peak_gain [rad/rad]" in md


def test_study_results_plot_themselves():
    """The chapter studies return typed results whose ``.plot()`` labels every trace and axis unit
    (ch. 3 constant-speed run, ch. 12 pole sweep, ch. 15 runs and stiffness check, ch. 16 gain samples)."""
    import matplotlib.pyplot as plt

    from awiwi_drake.parameters.backstepping import OptimalGainsStudy
    from awiwi_drake.parameters.components import MotorParams
    from awiwi_drake.reproductions.ch03_motor import constant_velocity_run
    from awiwi_drake.reproductions.ch12_pole_placement import open_loop_pole_sweep
    from awiwi_drake.reproductions.ch15_backstepping import antagonistic_stiffness_check, position_gain_study
    from awiwi_drake.reproductions.ch15_pip_experiments import pip_experiment
    from awiwi_drake.reproductions.ch16_optimal_backstepping import fig_16_3_gain_samples

    results = [constant_velocity_run(MotorParams(), 1.0, 0.02, kp=10.0, kd=0.1),
               position_gain_study(values=(5.0,), t_final=0.05)[0],
               antagonistic_stiffness_check([0.02, 0.05]),
               pip_experiment("cascaded", "step", t_final=0.06),
               fig_16_3_gain_samples(OptimalGainsStudy(runs=1, samples=20, t_final=0.05, num=11))]
    for r in results:
        fig, ax = r.plot()
        _check_axes_explained([ax])
        plt.close(fig)
    fig, axes = open_loop_pole_sweep(num=3).plot()
    _check_axes_explained(axes, need_legend=False)
    assert all(a.collections for a in axes)                    # one scatter of poles per panel
    plt.close(fig)
