"""``awiwi-drake demo``: simulate the joint rig demo and write plots, diagrams and a summary."""

from __future__ import annotations

import pathlib

import numpy as np

from awiwi_drake.analysis import linearize, rig_monitors, simulate
from awiwi_drake.components.spring import LeverSpringMechanism
from awiwi_drake.config import short_mode
from awiwi_drake.control.motor_position import demo_references, joint_rig_position_loop
from awiwi_drake.parameters.rigs import DemoScenario
from awiwi_drake.plotting import plot_pole_sweep, plot_signals, plot_spring_curve
from awiwi_drake.rigs.rigs import joint_rig

__all__ = ["run_demo", "pole_sweep_pretension"]


def pole_sweep_pretension(rig, pretensions):
    """Poles and joint stiffness of ``rig`` linearised at each pretension (link at 0)."""
    poles, stiffness = [], []
    for f0 in pretensions:
        op = rig.operating_point(pretension=float(f0))
        poles.append(linearize(rig, op).poles)
        stiffness.append(op.info["joint_stiffness"])
    return np.array(poles), np.array(stiffness)


def run_demo(out: pathlib.Path, *, backend: str = "compiled"):
    """Run the demo and write ``out/*.png``; return ``(summary text, {graph stem: diagram})``.

    The caller (``awiwi-drake demo``) writes the returned diagrams' graphs with
    :func:`awiwi_drake.export.export_diagram` (export sits above this layer).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rig = joint_rig(backend=backend)
    scenario = DemoScenario(t_final=1.0 if short_mode() else DemoScenario().t_final)
    loop = joint_rig_position_loop(rig, scenario)
    t_ref, refs = demo_references(rig, scenario)
    diagram = loop.diagram
    ctx = loop.create_context(rig.operating_point(pretension=scenario.f_start))
    result = simulate(diagram, ctx, scenario.t_final, log=("link_angle", "tendon_force", "motor_torque"),
                      monitors=rig_monitors(rig), max_step=1.0 / 3000)
    fig, _ = plot_signals(result, ["link_angle", "tendon_force", "motor_torque"],
                          labels=dict(link_angle="link angle [rad]", tendon_force="tendon force [N]",
                                      motor_torque="motor torque [Nm]"),
                          reference=dict(link_angle=(t_ref, refs["link_reference"]),
                                         tendon_force=(t_ref, refs["pretension"])))
    fig.suptitle("joint_rig: pretension ramp, then a link step (3 kHz motor PD)")
    fig.savefig(out / "demo_joint_rig.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    lever = LeverSpringMechanism(rig.params.spring.geometry)
    fig, _ = plot_spring_curve(lever, rig.spring)
    fig.savefig(out / "spring_curve.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    pre = np.linspace(5, 60, 8 if short_mode() else 23)
    poles, stiff = pole_sweep_pretension(joint_rig(backend=backend), pre)
    fig, ax = plot_pole_sweep(pre, poles, "pretension [N]")
    ax.set_title("joint_rig poles versus pretension (Linearize)")
    fig.savefig(out / "poles_vs_pretension.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    q_end = float(result["link_angle"][-1, 0])
    f_end = result["tendon_force"][-1]
    lines = [
        f"demo: joint_rig ({backend} backend) simulated {scenario.t_final} s; outputs in {out}/",
        f"  link angle at the end: {q_end:.4f} rad (reference {scenario.link_step} rad)",
        f"  tendon forces at the end: {f_end[0]:.2f} N, {f_end[1]:.2f} N (pretension {scenario.f_end} N)",
        f"  joint stiffness from {pre[0]:.0f} N to {pre[-1]:.0f} N pretension: {stiff[0]:.3f} -> {stiff[-1]:.3f} Nm/rad",
        f"  events: {len(result.events)}" + "".join(f"\n    {e}" for e in result.events),
        "  files: demo_joint_rig.png, spring_curve.png, poles_vs_pretension.png, joint_rig*.dot/.svg/.png",
    ]
    return "\n".join(lines), {"joint_rig_position_loop": diagram, "joint_rig": rig.diagram}
