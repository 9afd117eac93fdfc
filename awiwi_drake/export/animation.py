"""Meshcat recording of a finger or the hand to a self-contained HTML file (offline).

The geometry is one cylinder per link with a sphere at each joint, coloured per
finger (``plant.add_finger(visual=True)``, link lengths and radii from the
kinematic tables), the palm box and a forearm stub; the motion is a joint-space
grasp (open -> closed -> open) tracked by the 3 kHz joint controller through
the full tendon model.  The camera frames the moving links (see
:class:`~awiwi_drake.parameters.cli.AnimationParams`); the Meshcat server
that Drake needs to build the scene is started without log output.
"""

from __future__ import annotations

import logging
import math
import pathlib
from dataclasses import dataclass

import numpy as np
from pydrake.geometry import Cylinder, Meshcat, MeshcatVisualizer, MeshcatVisualizerParams, Rgba
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from awiwi_drake.analysis.simulate import simulate
from awiwi_drake.hand.diagrams import finger_diagram, hand_diagram
from awiwi_drake.parameters.cli import AnimationParams
from awiwi_drake.parameters.hand import FINGERS

__all__ = ["GRASP_POSE", "grasp_pose", "AnimationResult", "record_animation", "quiet_meshcat", "DISPLAY_ROTATION",
           "frame_camera"]

# Palm frame -> display frame: fingers (palm x) up (display z), palmar normal (palm z) towards display x,
# thumb side (palm y) towards display -y.  A proper rotation (det = +1).
DISPLAY_ROTATION = np.array([[0.0, 0.0, 1.0],
                             [0.0, -1.0, 0.0],
                             [1.0, 0.0, 0.0]])

# Chosen closed-hand pose [rad] per finger (plant joints; coupled DIPs follow (5.16)).
GRASP_POSE = {"thumb": [0.5, 0.35, 0.5, 0.4], "index": [0.05, 0.8, 0.9, 0.6], "middle": [0.0, 0.85, 0.9, 0.6],
              "ring": [-0.05, 0.85, 0.9], "fifth": [0.2, -0.1, 0.8, 0.9]}


def grasp_pose(rig) -> np.ndarray:
    """The grasp pose as plant joint angles of ``rig`` (DIPs of ring/fifth from (5.16)-(5.17))."""
    q = []
    for name, c in rig.coupling.parts.items():
        q.append(c.dof_selection @ np.asarray(GRASP_POSE[name], float))
    return np.concatenate(q)


@dataclass
class AnimationResult:
    """Where the HTML went, what was simulated and where the camera looks.

    ``camera_position`` and ``camera_target`` are in Drake's z-up world frame
    of the viewer [m] (the display frame, see :data:`DISPLAY_ROTATION`).
    """

    path: pathlib.Path
    duration: float
    max_tracking_error: float     # [rad] over the motion
    num_frames: int
    camera_position: np.ndarray
    camera_target: np.ndarray


def quiet_meshcat() -> Meshcat:
    """A Meshcat instance whose "listening for connections" log line is suppressed.

    Drake must run a Meshcat server to build a scene even when only
    :meth:`Meshcat.StaticHtml` is wanted; the log line would be noise then.
    """
    logger = logging.getLogger("drake")
    old = logger.level
    logger.setLevel(logging.WARNING)
    try:
        return Meshcat()
    finally:
        logger.setLevel(old)


def _link_points(rig, joint_angle_sets) -> np.ndarray:
    """Positions [m] (palm frame) of every body origin and fingertip over the given joint angles."""
    plant = rig.plant
    ctx = plant.CreateDefaultContext()
    models = rig.models
    models = models.values() if isinstance(models, dict) else (models if isinstance(models, (list, tuple))
                                                                else [models])
    pts = []
    for q in joint_angle_sets:
        plant.SetPositions(ctx, np.asarray(q, float))
        for m in models:
            for b in m.bodies:
                pts.append(plant.EvalBodyPoseInWorld(ctx, b).translation())
            X = plant.EvalBodyPoseInWorld(ctx, m.tip_body)
            pts.append(X.multiply(np.asarray(m.tip_offset, float)))
    return np.array(pts)


def frame_camera(points: np.ndarray, params: AnimationParams | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Camera position and target [m] (display frame) that show all ``points`` (display frame).

    The target is the centre of the points' bounding box (grown by
    ``params.margin``); the camera sits along the chosen azimuth/elevation at
    the distance where the box's bounding sphere fills ``fill_fraction`` of the
    height of the view (vertical field of view ``field_of_view``).
    """
    p = params or AnimationParams()
    pts = np.asarray(points, float).reshape(-1, 3)
    lo, hi = pts.min(axis=0) - p.margin, pts.max(axis=0) + p.margin
    target = 0.5 * (lo + hi)
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    half_fov = math.radians(p.field_of_view) / 2
    distance = radius / (p.fill_fraction * math.tan(half_fov))
    az, el = p.camera_azimuth, p.camera_elevation
    direction = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    return target + distance * direction, target


def record_animation(out, *, target: str = "hand", duration: float = 1.5, meshcat: Meshcat | None = None, params: AnimationParams | None = None,
                     progress=None) -> AnimationResult:
    """Simulate a grasp of ``target`` (a rig's name: ``"hand"`` or ``"finger-<f>"``) and write ``out`` (HTML).

    The HTML is self-contained (opens offline) and holds the geometry, the
    motion and the camera framed on the moving links.  ``progress(t, duration)`` is passed to :func:`simulate` (e.g.
    :class:`awiwi_drake.config.SimulationProgress`).  Returns an :class:`AnimationResult`.
    """
    targets = ("hand", *(f"finger-{f}" for f in FINGERS))
    if target not in targets:
        raise ValueError(f"target = {target!r}: not a hand rig (one of {', '.join(targets)})")
    if not (isinstance(duration, (int, float)) and math.isfinite(duration) and duration > 0):
        raise ValueError(f"duration = {duration} must be a finite number > 0 [s]")
    p = params or AnimationParams()
    out = pathlib.Path(out)
    if out.suffix.lower() not in (".html", ".htm"):
        raise ValueError(f"out = {str(out)!r}: the recording is written as HTML (use a .html file name)")
    rig = hand_diagram(visual=True) if target == "hand" else finger_diagram(finger=target[len("finger-"):], visual=True)
    from awiwi_drake.control import closed_loop, make_controller
    cl = closed_loop(rig, make_controller("joint-pd", rig))
    op = rig.operating_point()
    q0 = op.joint_angle
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
    meshcat = meshcat or quiet_meshcat()
    vis = MeshcatVisualizer.AddToBuilder(b, sys.GetOutputPort("query_object"), meshcat,
                                         MeshcatVisualizerParams(publish_period=1.0 / p.frame_rate))
    b.ExportOutput(sys.GetOutputPort("joint_angle"), "joint_angle")
    b.ExportOutput(ref.get_output_port(), "joint_angle_reference")
    d = b.Build()
    ctx = d.CreateDefaultContext()
    cl.initialize(ctx, state=op.state, motor_torque=op.motor_torque)
    # the scene: display frame, forearm stub (hand only), camera on the moving links
    R = RotationMatrix(DISPLAY_ROTATION)
    meshcat.SetTransform("/drake", RigidTransform(R, np.zeros(3)))
    if target == "hand" and p.forearm_length > 0:
        hp = rig.params.hand
        meshcat.SetObject("/drake/forearm_stub", Cylinder(p.forearm_radius, p.forearm_length),
                          Rgba(0.62, 0.62, 0.62, 1.0))
        # cylinder axis along palm -x, from the wrist (palm x = 0) backwards, under the palm centre
        X = RigidTransform(RotationMatrix.MakeYRotation(np.pi / 2),
                           [-p.forearm_length / 2, 0.25 * hp.finger_spacing, -0.008])
        meshcat.SetTransform("/drake/forearm_stub", X)
    meshcat.SetProperty("/Grid", "visible", bool(p.show_grid))
    meshcat.SetProperty("/Axes", "visible", False)
    pts = _link_points(rig, [q0, q1]) @ DISPLAY_ROTATION.T
    cam, look_at = frame_camera(pts, p)
    meshcat.SetCameraPose(cam, look_at)
    vis.StartRecording(set_transforms_while_recording=False)
    res = simulate(d, ctx, duration, log=("joint_angle", "joint_angle_reference"), max_step=1.0 / 3000,
                   accuracy=1e-3, progress=progress)
    vis.StopRecording()
    vis.PublishRecording()
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(meshcat.StaticHtml())
    err = float(np.max(np.abs(res["joint_angle"] - res["joint_angle_reference"])))
    return AnimationResult(out, duration, err, int(np.ceil(duration * p.frame_rate)), cam, look_at)
