"""Thesis Fig 15.24 / 15.25: the PIP joint of a finger under antagonistic backstepping and cascaded control.

Section 15.5.3 tests both controllers "on a single finger ... with bearings and steel cables": a
step (Fig 15.24, ~30 deg, pretension 10 N, 0.8 s) and a sine (Fig 15.25, ~10-50 deg, pretension
15 N), at the hand's 3 kHz; the cascaded controller is less accurate and its sine shows
stick-slip vibrations.

Model (chosen where the thesis gives no numbers):

* the PIP as the antagonistic joint rig (:func:`awiwi_drake.rigs.joint_rig`, two motors and
  lever springs), with the index finger's PIP pulley radius r22 and the inertia of the middle +
  distal phalanx about the PIP axis taken from the finger's MultibodyPlant (straight finger);
* link-side stick-slip friction (:class:`awiwi_drake.control.friction_observer.LinkFriction`,
  Stribeck, :class:`~awiwi_drake.parameters.hand_control.LinkFrictionParams`, with a smoothing
  velocity that keeps the explicit integrator's steps near 0.1 ms at this inertia) on the link's
  ``external_torque`` input;
* both controllers sampled at 3 kHz with their registered gains: backstepping
  (:mod:`awiwi_drake.control.backstepping_registry`, Kd,imp clamped to m f_s / 4) and cascaded
  (11.16) (:mod:`awiwi_drake.control.impedance`);
* step 0 -> 30 deg at 0.05 s, 0.8 s, pretension 10 N; sine 30 + 20 sin(2 pi t) deg, 2.6 s,
  pretension 15 N (the figure's axes), reference derivatives given to both; these numbers and their
  sources are :class:`awiwi_drake.parameters.PipStudy`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from awiwi_drake.parameters.backstepping import PipStudy
from awiwi_drake.parameters.control import CONTROL_RATE_HZ
from awiwi_drake.plotting import plot_traces

__all__ = ["PipRun", "pip_parameters", "pip_experiment", "pip_metrics"]

RATE_HZ = CONTROL_RATE_HZ


@dataclass
class PipRun:
    """One Fig 15.24/15.25 run: time [s], link angle and reference [rad], motor torques [Nm],
    friction torque [Nm], tendon forces [N]."""

    controller: str
    test: str
    t: np.ndarray
    q: np.ndarray
    reference: np.ndarray
    torque: np.ndarray
    friction: np.ndarray
    tendon_force: np.ndarray

    def plot(self, ax=None):
        """Link angle and reference [deg] (Fig 15.24 / 15.25)."""
        return plot_traces(self.t, {f"{self.controller} ({self.test})": np.degrees(self.q)},
                           reference=np.degrees(self.reference), ylabel="PIP angle [deg]", ax=ax,
                           legend=dict(fontsize="small"))


def pip_parameters(pretension: float):
    """JointRigParams of the index PIP: r22, inertia of middle + distal about the PIP (finger plant)."""
    from awiwi_drake.hand.plant import make_finger_plant
    from awiwi_drake.parameters.hand import finger_params
    from awiwi_drake.parameters.rigs import JointRigParams
    plant, _ = make_finger_plant("index")
    M = plant.CalcMassMatrix(plant.CreateDefaultContext())
    fp = finger_params("index")
    return JointRigParams(link_inertia=float(M[2, 2]), link_pulley_radius=fp.pip_radius,
                          link_damping=fp.joint_damping, pretension=float(pretension))


def _friction_params():
    from awiwi_drake.parameters.hand_control import LinkFrictionParams
    return LinkFrictionParams(smoothing_velocity=PipStudy().friction_smoothing_velocity)


def _controller(name: str, rig):
    from awiwi_drake.control.backstepping import impedance_controller
    from awiwi_drake.control.impedance import impedance_controller as linear_impedance
    from awiwi_drake.parameters.backstepping import AntagonisticBacksteppingGains
    if name == "backstepping":
        from awiwi_drake.control.backstepping_registry import _sampled_damping
        g = AntagonisticBacksteppingGains()
        g = g.replace(damping=_sampled_damping(rig, g.damping))     # the registry's 3 kHz limit (one place)
        return impedance_controller(rig, g, pretension=rig.params.pretension, reference_derivatives=4)
    if name == "cascaded":
        return linear_impedance(rig, mode="cascaded")
    raise ValueError(f"pip_experiment: controller must be 'backstepping' or 'cascaded', got {name!r}")


def _reference(test: str):
    """(schedule of the reference port: angle and four derivatives, duration [s], pretension [N])."""
    from awiwi_drake.analysis import PerEntry, Step
    s = PipStudy()
    if test == "step":
        return PerEntry([Step(s.step_time, s.step), 0.0, 0.0, 0.0, 0.0]), s.step_duration, s.step_pretension
    if test == "sine":
        from awiwi_drake.reproductions.ch15_backstepping import sine_reference
        return sine_reference(s.sine_amplitude, s.sine_frequency, s.sine_offset), s.sine_duration, s.sine_pretension
    raise ValueError(f"pip_experiment: test must be 'step' or 'sine', got {test!r}")


def pip_experiment(controller: str, test: str, *, friction: bool = True, t_final: float | None = None,
                   dt: float = 1.0 / RATE_HZ) -> PipRun:
    """Run one controller on one test (see the module docstring); ``friction=False`` removes the
    stick-slip friction (to show what it costs)."""
    from awiwi_drake.analysis import PerEntry, simulate
    from awiwi_drake.control.base import closed_loop
    from awiwi_drake.control.friction_observer import with_link_friction
    from awiwi_drake.rigs import joint_rig
    ref, t_end, pretension = _reference(test)
    t_end = t_end if t_final is None else float(t_final)
    rig = joint_rig(params=pip_parameters(pretension))
    ctrl = _controller(controller, rig)
    loop = closed_loop(rig, ctrl, rate_hz=RATE_HZ)
    q0 = float(ref.value(0.0)[0])
    op = rig.operating_point(pretension=pretension, joint_angle=q0)
    loop_ctx = loop.create_context(state=op.state, motor_torque=op.motor_torque,
                                   references={"joint_angle_reference": q0})   # before embedding
    fp = _friction_params() if friction else _friction_params().replace(coulomb=0.0, static=0.0, viscous=0.0)
    diagram, cl, fr = with_link_friction(loop.diagram, fp)
    ctx = diagram.CreateDefaultContext()
    # copy the loop's initialised state (rig at the operating point, hold buffers, controller states)
    cl_ctx = cl.GetMyMutableContextFromRoot(ctx)
    cl_ctx.SetContinuousState(loop_ctx.get_continuous_state_vector().CopyToVector())
    for i in range(loop_ctx.num_discrete_state_groups()):
        cl_ctx.SetDiscreteState(i, loop_ctx.get_discrete_state(i).CopyToVector())
    if loop_ctx.num_abstract_states():
        raise RuntimeError("pip_experiment: the loop has abstract state; copy it too")
    size = diagram.GetInputPort("joint_angle_reference").size()
    # error control (steps near 0.1 ms): the stick-slip friction is stiff for a fixed 3 kHz step
    res = simulate(diagram, ctx, t_end, inputs={"joint_angle_reference": PerEntry(ref.entries[:size])},
                   log=("joint_angle", "joint_angle_reference", "applied_torque", "link_friction", "tendon_force"),
                   log_period=dt, mode="error_controlled", max_step=PipStudy().max_step,
                   accuracy=PipStudy().accuracy)
    return PipRun(controller, test, res.t, res["joint_angle"][:, 0], res["joint_angle_reference"][:, 0],
                  res["applied_torque"], res["link_friction"][:, 0], res["tendon_force"])


def pip_metrics(run: PipRun) -> dict:
    """Step: final error [rad] (mean over the last 0.1 s), rise time 10-90 % [s], overshoot [%];
    sine: RMS error after the first period [rad]; both: velocity reversals of the link per second
    while the reference moves monotonically (stick-slip vibration count), peak |torque| [Nm],
    minimum tendon force [N]."""
    out = dict(peak_torque=float(np.max(np.abs(run.torque))), min_tendon_force=float(np.min(run.tendon_force)))
    e = run.q - run.reference
    dq = np.diff(run.q)
    if run.test == "step":
        m = run.t >= 0.05
        q1 = run.reference[-1]
        tail = run.t >= run.t[-1] - 0.1
        out["final_error"] = float(np.mean(np.abs(e[tail])))
        y = run.q[m] / q1
        i10 = np.argmax(y >= 0.1)
        i90 = np.argmax(y >= 0.9)
        out["rise_time"] = float(run.t[m][i90] - run.t[m][i10]) if np.any(y >= 0.9) else math.nan
        out["overshoot"] = float(max(0.0, 100 * (np.max(y) - 1)))
        moving = m[1:]
    else:
        after = run.t >= 1.0
        out["rms_error"] = float(np.sqrt(np.mean(e[after] ** 2)))
        dr = np.diff(run.reference)
        moving = after[1:] & (np.abs(dr) > 1e-9)
        dq = np.where(moving, dq * np.sign(dr), dq)
    s = np.sign(dq[moving & (np.abs(dq) > 1e-7)])
    dur = float(np.sum(moving)) * (run.t[1] - run.t[0])
    out["reversals_per_s"] = float(np.sum(s[1:] != s[:-1]) / dur) if dur > 0 and len(s) > 1 else 0.0
    return out
