"""``awiwi-drake demo``: simulate the joint rig demo and write plots, diagrams and a summary."""

from __future__ import annotations

import pathlib

import numpy as np

from awiwi_drake.analysis import poles_vs_pretension, rig_monitors, simulate
from awiwi_drake.components.spring import LeverSpringMechanism
from awiwi_drake.config import short_mode
from awiwi_drake.control.motor_position import demo_references, joint_rig_position_loop
from awiwi_drake.parameters.control import CONTROL_RATE_HZ
from awiwi_drake.parameters.rigs import DemoScenario
from awiwi_drake.plotting import plot_signals, plot_spring_curve
from awiwi_drake.rigs.rigs import joint_rig

__all__ = ["run_demo", "demo_figure"]


def demo_figure(result, t_ref, refs, scenario, *, torque_limit=None):
    """The demo's figure: the whole run (left) and a zoom on the link step (right).

    Link angle with its reference; both tendon forces with the pretension
    reference; the torque applied to each motor (after the motor's saturation,
    solid) beside the commanded torque (dotted) and the torque limit.  Shaded
    intervals are events (named in the legend).
    """
    from awiwi_drake.plotting import _plt

    plt = _plt()
    names = ["joint_angle", "tendon_force", "applied_torque"]
    labels = dict(joint_angle="link angle [rad]", tendon_force="tendon force [N]",
                  applied_torque="motor torque [Nm]")
    kw = dict(labels=labels,
              reference=dict(joint_angle=(t_ref, refs["link_reference"]), tendon_force=(t_ref, refs["pretension"])),
              components=dict(joint_angle=["link angle"], tendon_force=["tendon 1", "tendon 2"],
                              applied_torque=["motor 1 applied", "motor 2 applied"]),
              overlay=dict(applied_torque=(result["motor_torque_command"], ["motor 1 commanded", "motor 2 commanded"])),
              limits=dict(applied_torque=torque_limit) if torque_limit else None)
    fig, ax = plt.subplots(3, 2, figsize=(12, 7.5), sharex="col", gridspec_kw=dict(width_ratios=[1.6, 1]))
    plot_signals(result, names, ax=ax[:, 0], **kw)
    window = (scenario.step_time - 0.02, min(scenario.step_time + 0.15, float(result.t[-1])))
    plot_signals(result, names, ax=ax[:, 1], xlim=window, legend=False, **kw)
    for a in ax[:, 1]:  # y range of the zoom from the data inside the window
        ys = [ln.get_ydata()[(ln.get_xdata() >= window[0]) & (ln.get_xdata() <= window[1])]
              for ln in a.get_lines() if len(np.atleast_1d(ln.get_xdata())) > 2]
        ys = np.concatenate([y for y in ys if y.size]) if ys else np.zeros(1)
        pad = 0.08 * (np.ptp(ys) or 1.0)
        a.set_ylim(ys.min() - pad, ys.max() + pad)
        a.set_ylabel("")
    ax[0, 0].set_title(f"whole run: pretension ramp {scenario.f_start:g} -> {scenario.f_end:g} N, "
                       f"then a {scenario.link_step:g} rad step", fontsize=9)
    ax[0, 1].set_title(f"zoom on the step at {scenario.step_time:g} s", fontsize=9)
    ax[-1, 1].set_xlabel("time [s]")
    fig.suptitle("joint-rig: motor-position PD at 3 kHz (applied = after the motor's torque saturation)")
    fig.tight_layout()
    return fig


def run_demo(out: pathlib.Path, *, scenario: DemoScenario | None = None):
    """Run the demo and write ``out/*.png``; return ``(summary text, {graph stem: diagram})``.

    ``scenario`` (default: :class:`DemoScenario`, 1 s long in short mode) sets the
    pretension ramp and the link step; ``awiwi-drake demo --config FILE.yaml`` reads it.

    The caller (``awiwi-drake demo``) writes the returned diagrams' graphs with
    :func:`awiwi_drake.export.export_diagram` (export sits above this layer).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rig = joint_rig()
    if scenario is None:
        scenario = DemoScenario(t_final=1.0 if short_mode() else DemoScenario().t_final)
    loop = joint_rig_position_loop(rig, scenario)
    t_ref, refs = demo_references(rig, scenario)
    diagram = loop.diagram
    ctx = loop.create_context(rig.operating_point(pretension=scenario.f_start))
    result = simulate(diagram, ctx, scenario.t_final,
                      log=("joint_angle", "tendon_force", "motor_torque", "motor_torque_command", "applied_torque"),
                      monitors=rig_monitors(rig), max_step=1.0 / CONTROL_RATE_HZ)
    fig = demo_figure(result, t_ref, refs, scenario, torque_limit=rig.torque_limit)
    fig.savefig(out / "demo_joint_rig.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    lever = LeverSpringMechanism(rig.params.spring.geometry)
    fig, _ = plot_spring_curve(lever, rig.spring)
    fig.savefig(out / "spring_curve.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    pre = np.linspace(5, 60, 8 if short_mode() else 23)
    sweep = poles_vs_pretension(joint_rig(), pre)
    stiff = sweep.joint_stiffness
    fig, ax = sweep.plot(symlog=0.01)  # slow poles at -0.03..-0.1 1/s
    ax.set_title("joint-rig poles versus pretension (Linearize)")
    fig.savefig(out / "poles_vs_pretension.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    q_end = float(result["joint_angle"][-1, 0])
    f_end = result["tendon_force"][-1]
    lines = [
        f"demo: joint-rig simulated {scenario.t_final} s; outputs in {out}/",
        f"  link angle at the end: {q_end:.4f} rad (reference {scenario.link_step} rad)",
        f"  tendon forces at the end: {f_end[0]:.2f} N, {f_end[1]:.2f} N (pretension {scenario.f_end} N)",
        f"  joint stiffness from {pre[0]:.0f} N to {pre[-1]:.0f} N pretension: {stiff[0]:.3f} -> {stiff[-1]:.3f} Nm/rad",
        f"  events: {len(result.events)}" + "".join(f"\n    {e}" for e in result.events),
        "  files: demo_joint_rig.png, spring_curve.png, poles_vs_pretension.png, joint_rig*.dot/.svg/.png",
    ]
    return "\n".join(lines), {"joint_rig_position_loop": diagram, "joint_rig": rig.diagram}
