"""Thesis ch. 6: the wrist seen from the fingers (results are data).

* :func:`wrist_compensation_study` - finger joint drift during a wrist
  abduction sweep, with and without the feedforward compensation ``-h_wrist / r_m`` ((6.9)).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from awiwi_drake.analysis import PerEntry, Sine, rig_monitors, simulate
from awiwi_drake.control import closed_loop
from awiwi_drake.control.joint_pd import joint_pd_controller
from awiwi_drake.hand.diagrams import finger_diagram, hand_diagram
from awiwi_drake.parameters.hand import JointControllerParams

__all__ = ["WristCompensationStudy", "wrist_compensation_study"]


@dataclass
class WristCompensationStudy:
    """Finger joint drift during a wrist abduction sweep (rows: time; columns: joints)."""

    t: np.ndarray
    wrist_abduction: np.ndarray
    drift_uncompensated: np.ndarray
    drift_compensated: np.ndarray
    joint_names: list
    min_tendon_force: dict
    events: dict            # "uncompensated"/"compensated" -> list of analysis.simulate.Event (slack, saturation)

    def max_drift(self) -> dict:
        """Largest |q - q_ref| [rad] over time and joints, per case."""
        return {"uncompensated": float(np.max(np.abs(self.drift_uncompensated))),
                "compensated": float(np.max(np.abs(self.drift_compensated)))}


def wrist_compensation_study(target: str = "index", *, backend: str = "compiled", amplitude: float = np.radians(5.0), frequency: float = 2.0,
                             t_final: float = 0.5, controller: JointControllerParams | None = None,
                             accuracy: float = 1e-3) -> WristCompensationStudy:
    """Sweep the wrist abduction ``q71 = amplitude sin(2 pi frequency t)`` [rad] under joint control.

    The joint references stay at the operating point; the drift is the joint
    motion the wrist causes through the tendon path change (6.9).  Run once
    without and once with the feedforward ``-h_wrist / r_m``.  ``target`` is
    a finger name or ``"hand"`` (a fresh rig with ``wrist=True`` per run).
    """
    drift, fmin, events = {}, {}, {}
    t_grid = np.linspace(0.0, t_final, 201)
    for comp in (False, True):
        rig = (hand_diagram(backend=backend, wrist=True) if target == "hand"
               else finger_diagram(finger=target, backend=backend, wrist=True))
        cl = closed_loop(rig, joint_pd_controller(rig, controller, wrist_compensation=comp))
        d = cl.diagram
        ctx = d.CreateDefaultContext()
        op = rig.operating_point()
        cl.initialize(ctx, state=op.state, motor_torque=op.motor_torque)
        q_op = op.joint_angle
        d.GetInputPort("joint_angle_reference").FixValue(ctx, q_op)
        d.GetInputPort("external_torque").FixValue(ctx, np.zeros(rig.num_joints))
        res = simulate(d, ctx, t_final, inputs={"wrist_angle": PerEntry([Sine(amplitude, frequency), 0.0])},
                       log=("joint_angle", "tendon_force"), monitors=rig_monitors(rig),
                       max_step=1.0 / cl.rate_hz, accuracy=accuracy)
        events[comp] = list(res.events)
        res = res.resample(t_grid)
        drift[comp] = res["joint_angle"] - q_op
        fmin[comp] = float(np.min(res["tendon_force"]))
    return WristCompensationStudy(t_grid, amplitude * np.sin(2 * np.pi * frequency * t_grid), drift[False],
                                  drift[True], list(rig.joint_names),
                                  {"uncompensated": fmin[False], "compensated": fmin[True]},
                                  {"uncompensated": events[False], "compensated": events[True]})
