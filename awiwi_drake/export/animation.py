"""Meshcat recording of a finger or the hand to a self-contained HTML file (offline).

The geometry is one cylinder per link (``plant.add_finger(visual=True)``);
the motion is a joint-space grasp (open -> closed -> open) tracked by the
3 kHz joint controller through the full tendon model.
"""

from __future__ import annotations

import pathlib
from dataclasses import dataclass

import numpy as np
from pydrake.geometry import Meshcat, MeshcatVisualizer, MeshcatVisualizerParams
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from awiwi_drake.analysis.simulate import simulate
from awiwi_drake.hand.diagrams import closed_loop, finger_diagram, hand_diagram
from awiwi_drake.parameters.hand import FINGERS

__all__ = ["GRASP_POSE", "grasp_pose", "AnimationResult", "record_animation"]

# Chosen closed-hand pose [rad] per finger (plant joints; coupled DIPs follow (5.16)).
GRASP_POSE = {"thumb": [0.5, 0.35, 0.5, 0.4], "index": [0.05, 0.8, 0.9, 0.6], "middle": [0.0, 0.85, 0.9, 0.6],
              "ring": [-0.05, 0.85, 0.9], "fifth": [0.2, -0.1, 0.8, 0.9]}


def grasp_pose(rig) -> np.ndarray:
    """The grasp pose as plant joint angles of ``rig`` (DIPs of ring/fifth from (5.16)-(5.17))."""
    coupling = rig.extra["coupling"]
    parts = coupling.parts if hasattr(coupling, "parts") else {rig.name.replace("finger_", ""): coupling}
    q = []
    for name, c in parts.items():
        q.append(c.dof_selection @ np.asarray(GRASP_POSE[name], float))
    return np.concatenate(q)


@dataclass
class AnimationResult:
    """Where the HTML went and what was simulated."""

    path: pathlib.Path
    duration: float
    max_tracking_error: float     # [rad] over the motion
    num_frames: int


def record_animation(out, *, target: str = "hand", duration: float = 1.5, backend: str = "python",
                     meshcat: Meshcat | None = None) -> AnimationResult:
    """Simulate a grasp of ``target`` ("hand" or a finger name) and write ``out`` (HTML).

    ``backend="python"`` is the faster drive for the whole hand (see
    benchmarks/bench_hand.py).  Returns an :class:`AnimationResult`.
    """
    if target != "hand" and target not in FINGERS:
        raise ValueError(f"target must be 'hand' or one of {FINGERS}, got {target!r}")
    if not duration > 0:
        raise ValueError(f"duration = {duration} must be > 0 [s]")
    out = pathlib.Path(out)
    if out.suffix.lower() not in (".html", ".htm"):
        raise ValueError(f"out = {str(out)!r}: the recording is written as HTML (use a .html file name)")
    rig = (hand_diagram(backend=backend, visual=True) if target == "hand"
           else finger_diagram(finger=target, backend=backend, visual=True))
    cl = closed_loop(rig)
    q0 = cl.operating_point.info["joint_angles"]
    q1 = grasp_pose(rig)
    b = DiagramBuilder()
    sys = b.AddSystem(cl.diagram)
    times = [0.0, 0.1 * duration, 0.5 * duration, 0.6 * duration, duration]
    knots = np.stack([q0, q0, q1, q1, q0], axis=1)
    ref = b.AddNamedSystem("grasp_reference", TrajectorySource(PiecewisePolynomial.FirstOrderHold(times, knots)))
    b.Connect(ref.get_output_port(), sys.GetInputPort("joint_angle_reference"))
    zero = b.AddNamedSystem("no_external_torque", ConstantVectorSource(np.zeros(rig.num_joints)))
    b.Connect(zero.get_output_port(), sys.GetInputPort("external_torque"))
    if sys.HasInputPort("wrist_angle"):
        w = b.AddNamedSystem("wrist_neutral", ConstantVectorSource(np.zeros(2)))
        b.Connect(w.get_output_port(), sys.GetInputPort("wrist_angle"))
    meshcat = meshcat or Meshcat()
    vis = MeshcatVisualizer.AddToBuilder(b, sys.GetOutputPort("query_object"), meshcat,
                                         MeshcatVisualizerParams(publish_period=1.0 / 30))
    b.ExportOutput(sys.GetOutputPort("joint_angle"), "joint_angle")
    b.ExportOutput(ref.get_output_port(), "joint_angle_reference")
    d = b.Build()
    ctx = d.CreateDefaultContext()
    ctx.SetContinuousState(cl.operating_point.state)
    cl.controller.hold.GetMyMutableContextFromRoot(ctx).SetDiscreteState(
        np.asarray(cl.operating_point.motor_torque, float))
    vis.StartRecording(set_transforms_while_recording=False)
    res = simulate(d, ctx, duration, log=("joint_angle", "joint_angle_reference"), max_step=1.0 / 3000,
                   accuracy=1e-3)
    vis.StopRecording()
    vis.PublishRecording()
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(meshcat.StaticHtml())
    err = float(np.max(np.abs(res["joint_angle"] - res["joint_angle_reference"])))
    return AnimationResult(out, duration, err, int(np.ceil(duration * 30)))
