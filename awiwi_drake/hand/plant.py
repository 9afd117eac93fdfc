"""Continuous MultibodyPlant models of the fingers and the hand (thesis 5.2.2, 5.3.2, 5.4.2).

Plants are continuous (``time_step=0``) so that a diagram containing them can be linearised; tendon
forces enter as generalised forces ``tau = -P(q)^T f`` (no actuators).  The PIP/DIP coupling of the
ring and fifth fingers (5.16)-(5.17) is *not* a constraint (coupler constraints need a discrete plant):
the DIP is a joint of its own, held to ``q_DIP = c q_PIP`` (``c = r_x3/r_x2``) by a stiff spring/damper,
the linear generalised force ``-G [q; v]`` of :func:`coupling_force_gain`.  Geometry for drawing is
optional: a cylinder per link (no collision).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydrake.geometry import Box, Cylinder, SceneGraph, Sphere
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.primitives import Adder, MatrixGain
from pydrake.multibody.tree import (FixedOffsetFrame, RevoluteJoint, RotationalInertia,
                                    SpatialInertia)

from ..parameters.hand import FINGERS, FingerParams, HandParams, ThumbParams, finger_params
from .kinematics import M21, finger_joint_names

__all__ = ["FingerModel", "add_finger", "make_finger_plant", "make_hand_plant",
           "coupling_force_gain", "add_applied_force_sum", "coupling_compliance", "finger_base_pose", "palm_centre"]

_COLORS = {"thumb": (0.85, 0.55, 0.45, 1.0), "index": (0.55, 0.65, 0.85, 1.0),
           "middle": (0.55, 0.8, 0.6, 1.0), "ring": (0.85, 0.8, 0.5, 1.0),
           "fifth": (0.75, 0.6, 0.85, 1.0)}


@dataclass
class FingerModel:
    """Handles of one finger in a plant."""

    finger: str
    params: FingerParams | ThumbParams
    joint_names: list[str]
    joints: list = field(default_factory=list)
    bodies: list = field(default_factory=list)
    tip_body: object = None
    tip_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def coupling_vector(self) -> np.ndarray | None:
        """``c`` with ``c . q = q_DIP - (r_x3/r_x2) q_PIP`` (coupled fingers), else None."""
        p = self.params
        if isinstance(p, ThumbParams) or not p.pip_dip_coupled:
            return None
        c = np.zeros(len(self.joint_names))
        c[-1], c[-2] = 1.0, -p.dip_pip_ratio
        return c


def _link_inertia(mass: float, length: float, radius: float) -> SpatialInertia:
    """Solid cylinder along +x from the body origin, centre of mass at length/2."""
    I_perp = mass * (length ** 2 / 12.0 + radius ** 2 / 4.0)
    I_cm = RotationalInertia(mass * radius ** 2 / 2.0, I_perp, I_perp)
    return SpatialInertia.MakeFromCentralInertia(mass, [length / 2.0, 0.0, 0.0], I_cm)


def _add_link(plant, name, mass, length, radius, color, visual, instance):
    body = plant.AddRigidBody(name, instance, _link_inertia(mass, length, radius))
    if visual and plant.geometry_source_is_registered():
        X_BG = RigidTransform(RotationMatrix.MakeYRotation(np.pi / 2), [length / 2, 0, 0])
        plant.RegisterVisualGeometry(body, X_BG, Cylinder(radius, max(length, 1e-3)), name + "_visual",
                                     np.array(color))
        plant.RegisterVisualGeometry(body, RigidTransform(), Sphere(radius * 1.05), name + "_joint",
                                     np.array(color) * np.array([0.8, 0.8, 0.8, 1.0]))
    return body


def _add_revolute(plant, name, parent_frame, X_PJ, child, axis, damping):
    F = plant.AddFrame(FixedOffsetFrame(name + "_parent", parent_frame, RigidTransform(X_PJ)))
    return plant.AddJoint(RevoluteJoint(name, F, child.body_frame(), np.asarray(axis, float), damping))


def add_finger(plant: MultibodyPlant, finger: str, params=None, *, X_PF=None, visual: bool = True) -> FingerModel:
    """Add one finger (bodies + revolute joints, Table 5.1 / (5.19)) to ``plant``, its base frame at ``X_PF`` in
    the world; joints named as in the thesis (``q20``..``q23``, ``q5h``, ``q10``..``q13``)."""
    if finger not in FINGERS:
        raise ValueError(f"finger must be one of {FINGERS}, got {finger!r}")
    p = params if params is not None else finger_params(finger)
    parent_frame = plant.world_frame()
    X_PF = np.eye(4) if X_PF is None else (X_PF.GetAsMatrix4() if isinstance(X_PF, RigidTransform) else X_PF)
    instance = plant.AddModelInstance(finger)
    model = FingerModel(finger, p, finger_joint_names(finger))
    color = _COLORS[finger]
    R = p.link_radius

    def link(name, mass, length):
        b = _add_link(plant, f"{finger}_{name}", mass, length, R, color, visual, instance)
        model.bodies.append(b)
        return b

    def joint(k, parent, X, child, axis):
        j = _add_revolute(plant, model.joint_names[k], parent, X, child, axis, p.joint_damping)
        model.joints.append(j)

    if finger == "thumb":
        base = link("base", p.base_link_mass, 1e-3)
        mc = link("metacarpal", p.metacarpal_mass, p.metacarpal_length)
        prox = link("proximal", p.proximal_mass, p.proximal_length)
        dist = link("distal", p.distal_mass, p.distal_length)
        joint(0, parent_frame, X_PF, base, [0, 0, 1])                      # q10 about z
        joint(1, base.body_frame(), np.eye(4), mc, [0, 1, 0])                # q11 about y
        T = np.eye(4)
        T[0, 3] = p.metacarpal_length
        joint(2, mc.body_frame(), T, prox, [0, 0, 1])                        # q12 (frame 12)
        T = np.eye(4)
        T[0, 3] = p.proximal_length
        joint(3, prox.body_frame(), T, dist, [0, 0, 1])                      # q13
        model.tip_body, model.tip_offset = dist, np.array([p.distal_length, 0, 0])
        return model

    k = 0
    frame, X = parent_frame, X_PF
    if p.has_hmc:
        mc = link("metacarpal", p.hmc_mass, p.hmc_offset)
        joint(0, frame, X, mc, p.hmc_axis)                                  # q5h: oblique, normal to the metacarpal
        frame, X = mc.body_frame(), np.eye(4)
        X[0, 3] = p.hmc_offset
        k = 1
    abd = link("abduction", p.abduction_link_mass, p.base_offset)
    joint(k, frame, X, abd, [0, 0, 1])                                      # M10
    prox = link("proximal", p.proximal_mass, p.proximal_length)
    T = M21.copy()
    T[0, 3] = p.base_offset                                                  # M21 M32
    joint(k + 1, abd.body_frame(), T, prox, [0, 0, 1])                      # M43
    mid = link("middle", p.middle_mass, p.middle_length)
    T = np.eye(4)
    T[0, 3] = p.proximal_length                                              # M54
    joint(k + 2, prox.body_frame(), T, mid, [0, 0, 1])                      # M65
    dist = link("distal", p.distal_mass, p.distal_length)
    T = np.eye(4)
    T[0, 3], T[2, 3] = p.middle_length, p.middle_lateral                     # M76
    joint(k + 3, mid.body_frame(), T, dist, [0, 0, 1])                      # M87
    model.tip_body, model.tip_offset = dist, np.array([p.distal_length, 0, p.distal_lateral])  # M98
    return model


def _new_plant(name: str, builder, visual: bool, scene_graph: SceneGraph | None) -> MultibodyPlant:
    """A continuous plant, added to ``builder`` as ``name`` or standalone; with ``visual`` its geometry is
    registered with ``scene_graph`` when one is given (the plant is then drawn through its positions)."""
    plant = MultibodyPlant(0.0) if builder is None else builder.AddNamedSystem(name, MultibodyPlant(0.0))
    if visual and scene_graph is not None:
        plant.RegisterAsSourceForSceneGraph(scene_graph)
    return plant


def make_finger_plant(finger: str, params=None, *, scene_graph: SceneGraph | None = None,
                      builder=None, visual: bool = False, gravity: bool = False):
    """``(plant, FingerModel)``: a finalised continuous plant holding one finger (base frame = world), added to
    ``builder`` or standalone, its visual geometry registered with ``scene_graph`` when one is given.  Gravity
    is off by default (section 5.2.2: ~0.002 N m, negligible)."""
    plant = _new_plant(f"{finger}_plant", builder, visual, scene_graph)
    model = add_finger(plant, finger, params, visual=visual)
    if not gravity:
        plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, 0.0])
    plant.Finalize()
    return plant, model


def finger_base_pose(finger: str, hp: HandParams) -> RigidTransform:
    """Chosen placement of each finger base in the palm frame (x: towards the fingers,
    y: towards the thumb, z: palm normal on the palmar side; fingers flex towards +z)."""
    s, L = hp.finger_spacing, hp.palm_length
    if finger == "thumb":
        return RigidTransform(RollPitchYaw(np.pi / 2, 0.0, 0.9), [0.3 * L, 1.8 * s, 0.015])
    y = {"index": 1.5 * s, "middle": 0.5 * s, "ring": -0.5 * s, "fifth": -1.5 * s}[finger]
    x = L if finger != "fifth" else L - hp.fifth.hmc_offset - 0.01
    return RigidTransform([x, y, 0.0])


def palm_centre(hp: HandParams) -> np.ndarray:
    """Centre of the palm's palmar surface [m] in the palm frame (the drawn palm box's centre,
    on its surface): halfway along the palm, midway between the thumb side and the fifth finger."""
    return np.array([hp.palm_length / 2, 0.25 * hp.finger_spacing, 0.0])


def make_hand_plant(params: HandParams | None = None, *, visual: bool = False, gravity: bool = False,
                    scene_graph: SceneGraph | None = None):
    """A finalised continuous plant with all five fingers on a fixed palm.

    Joint (position) order: thumb q10..q13, index q20..q23, middle q30..q33, ring q40..q43, fifth q5h,
    q50..q53 (21 joints, 19 DoF).  Returns ``(plant, {finger: FingerModel})``; ``visual`` geometry is
    registered with ``scene_graph`` when one is given.
    """
    hp = params or HandParams()
    plant = _new_plant("hand_plant", None, visual, scene_graph)
    if visual and plant.geometry_source_is_registered():
        palm = plant.world_body()
        plant.RegisterVisualGeometry(
            palm, RigidTransform(palm_centre(hp) - [0.0, 0.0, 0.008]),
            Box(hp.palm_length, 4.5 * hp.finger_spacing, 0.016), "palm_visual", np.array([0.7, 0.7, 0.7, 1.0]))
    models = {f: add_finger(plant, f, hp.finger(f), X_PF=finger_base_pose(f, hp), visual=visual)
              for f in FINGERS}
    if not gravity:
        plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, 0.0])
    plant.Finalize()
    return plant, models


def coupling_force_gain(plant: MultibodyPlant, models) -> np.ndarray | None:
    """``G`` (n x 2n) with ``tau_c = -G [q; v]`` for the PIP/DIP coupling elements (5.16)-(5.17).

    ``tau_c = -k_c c (c.q) - d_c c (c.v)`` per coupled finger: the
    generalised force of a spring/damper on ``e = q_DIP - (r_x3/r_x2) q_PIP``.
    Returns None when no finger is coupled.
    """
    models = models if isinstance(models, dict) else {models.finger: models}
    n = plant.num_positions()
    G = np.zeros((n, 2 * n))
    any_coupled = False
    for m in models.values():
        c_local = m.coupling_vector
        if c_local is None:
            continue
        any_coupled = True
        idx = [j.position_start() for j in m.joints]
        c = np.zeros(n)
        c[idx] = c_local
        G[:, :n] += m.params.coupling_stiffness * np.outer(c, c)
        G[:, n:] += m.params.coupling_damping * np.outer(c, c)
    return G if any_coupled else None


def add_applied_force_sum(b, plant: MultibodyPlant, sources: list, G: np.ndarray | None) -> None:
    """Wire ``sources`` (generalised-force output ports, n each), the coupling element ``-G [q; v]``
    (:func:`coupling_force_gain`; none when ``G`` is None) and an exported ``external_torque`` input
    into the plant's applied generalised force (the ``generalized_force_sum`` Adder)."""
    sources = list(sources)
    if G is not None:
        ce = b.AddNamedSystem("coupling_element", MatrixGain(-G))
        b.Connect(plant.get_state_output_port(), ce.get_input_port())
        sources.append(ce.get_output_port())
    adder = b.AddNamedSystem("generalized_force_sum", Adder(len(sources) + 1, plant.num_positions()))
    for i, src in enumerate(sources):
        b.Connect(src, adder.get_input_port(i))
    b.ExportInput(adder.get_input_port(len(sources)), "external_torque")
    b.Connect(adder.get_output_port(), plant.get_applied_generalized_force_input_port())


def coupling_compliance(joint_stiffness: np.ndarray, coupling_vector: np.ndarray,
                        joint: int | None = None) -> float:
    """Coupling error per unit torque on a joint [rad/(N m)]: ``c^T K_q^-1 e_joint``.

    ``joint_stiffness`` is the full motors-held stiffness ``K_q`` (n x n, e.g. ``op.joint_stiffness`` of a finger
    rig), ``coupling_vector`` the ``c`` of :attr:`FingerModel.coupling_vector` in the n plant joints; ``joint``
    defaults to the DIP (where ``c`` is 1).  For the ring/fifth routing the PIP/DIP tendon pair acts along
    ``(r_x2, r_x3)``, orthogonal to ``c``, so the result is ``1 / (k_c (1 + (r_x3/r_x2)^2))``.
    """
    K = np.asarray(joint_stiffness, dtype=float)
    c = np.asarray(coupling_vector, dtype=float).ravel()
    n = c.size
    if K.shape != (n, n):
        raise ValueError(f"coupling_compliance: joint_stiffness must be {n} x {n} like coupling_vector, got {K.shape}")
    if joint is None:
        hits = np.flatnonzero(c == 1.0)
        if hits.size != 1:
            raise ValueError("coupling_compliance: coupling_vector has no single DIP entry equal to 1; pass joint=")
        joint = int(hits[0])
    if not 0 <= joint < n:
        raise ValueError(f"coupling_compliance: joint = {joint} out of range 0..{n - 1}")
    e = np.zeros(n)
    e[joint] = 1.0
    return float(c @ np.linalg.solve(K, e))
