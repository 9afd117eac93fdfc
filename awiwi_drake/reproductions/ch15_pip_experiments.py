"""Thesis Fig 15.24 / 15.25: the PIP joint of a finger under antagonistic backstepping and cascaded control.

Section 15.5.3 tests both controllers "on a single finger ... with bearings and steel cables": a step (Fig 15.24,
~30 deg, pretension 10 N, 0.8 s) and a sine (Fig 15.25, 10-50 deg, pretension 15 N), at the hand's 3 kHz; the
cascaded controller is "inaccurate because the maximum impedance gain Kp,imp that can be selected without amplifying
the sensor noise is significantly lower", and its sine shows "vibrations ... caused by the stick-slip effect".

Here (numbers and sources in :class:`awiwi_drake.parameters.PipStudy`):

* the package's index finger (:func:`awiwi_drake.hand.finger_diagram`) with its drive physics (motor friction,
  ripple, spring hysteresis), no guide friction (bearings and steel cables) and the joints' stick-slip friction on
  (``with_physics(joint_friction=True)``, :func:`awiwi_drake.components.friction.stick_slip_rate`); the plant is
  integrated at ``plant_substeps`` x 3 kHz with the joints' presliding stiffness scaled by ``plant_substeps^2``
  (the RK3 bound that sets it at the hand's own step scales with ``1/h^2``);
* any registered finger controller closed at its registered 3 kHz with the joint angles estimated from the tendon
  lengths (5.15), designed at the figure's pretension: the 15.5 backstepping variants (``backstepping``,
  ``backstepping-friction-observer``, ...) and the cascaded chain (``cascaded``, with its ch. 9 observer, whose bound
  holds the joints' breakaway level, :func:`awiwi_drake.components.friction.joint_friction_bound`;
  ``cascaded:no-observer`` is the thesis's cascaded controller, which had none);
* the PIP steps from 0 to 30 deg at 0.05 s (10 N), or tracks 30 + 20 sin(2 pi t) deg from 30 deg (15 N); the other
  joints hold 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from awiwi_drake.parameters.backstepping import PipStudy
from awiwi_drake.parameters.control import CONTROL_RATE_HZ
from awiwi_drake.plotting import plot_traces

__all__ = ["PipRun", "pip_rig", "pip_experiment", "pip_metrics", "stuck_intervals", "PIP"]

RATE_HZ = CONTROL_RATE_HZ
PIP = 2                     # the index PIP, q22, in the finger's joint order


@dataclass
class PipRun:
    """One Fig 15.24/15.25 run on the index finger: time [s], PIP angle, reference and estimate [rad], PIP velocity
    [rad/s], the joints' friction torque on the PIP [Nm] (0 without it), applied motor torques [Nm], tendon forces [N];
    ``finger``: every joint's ``joint_angle``, ``joint_angle_estimate`` [rad], ``joint_friction_torque`` [Nm] and the
    plant's ``state`` (``pip_rig().state_names``) per sample (the rest's closed form needs them)."""

    controller: str
    test: str
    joint_friction: bool
    t: np.ndarray
    q: np.ndarray
    reference: np.ndarray
    estimate: np.ndarray
    velocity: np.ndarray
    friction: np.ndarray
    torque: np.ndarray
    tendon_force: np.ndarray
    finger: dict = field(default_factory=dict, repr=False)

    def plot(self, ax=None):
        """PIP angle and reference [deg] (Fig 15.24 / 15.25)."""
        label = f"{self.controller} ({self.test}{'' if self.joint_friction else ', no joint friction'})"
        return plot_traces(self.t, {label: np.degrees(self.q)}, reference=np.degrees(self.reference),
                           ylabel="PIP angle [deg]", ax=ax, legend=dict(fontsize="small"))


def pip_rig(joint_friction: bool = True, study: PipStudy | None = None):
    """The index finger of the study: no guide friction, the joints' stick-slip on (presliding stiffness scaled for
    the study's plant step), the rest of the drive physics as the default."""
    from awiwi_drake.hand import finger_diagram
    from awiwi_drake.parameters.hand import FingerRigParams
    s = study or PipStudy()
    p = FingerRigParams.for_finger("index").with_physics(guide_friction=s.guide_friction, joint_friction=joint_friction)
    jp = p.joint_friction_params
    p = p.replace(joint_friction_params=jp.replace(presliding_angle=jp.presliding_angle / s.plant_substeps ** 2))
    return finger_diagram(finger="index", params=p)


def _reference(test: str, s: PipStudy):
    """(PIP reference schedule, PIP angle at the start [rad], duration [s], pretension [N])."""
    from awiwi_drake.analysis import Sine, Step
    if test == "step":
        return Step(s.step_time, s.step, before=0.0), 0.0, s.step_duration, s.step_pretension
    if test == "sine":
        return (Sine(s.sine_amplitude, s.sine_frequency, offset=s.sine_offset), s.sine_offset, s.sine_duration,
                s.sine_pretension)
    raise ValueError(f"pip_experiment: test must be 'step' or 'sine', got {test!r}")


def pip_experiment(controller: str, test: str, *, joint_friction: bool = True, t_final: float | None = None,
                   study: PipStudy | None = None) -> PipRun:
    """Run one registered finger controller (e.g. ``backstepping``, ``backstepping-friction-observer``,
    ``cascaded``) on one test (``step`` or ``sine``) of the module docstring; ``joint_friction=False`` removes the
    joints' stick-slip (to show what it does); ``t_final`` shortens the run."""
    from awiwi_drake.analysis import Constant, PerEntry, simulate
    from awiwi_drake.control import closed_loop, make_controller
    from awiwi_drake.control.registry import get_entry
    s = study or PipStudy()
    pip, q0, t_end, pretension = _reference(test, s)
    t_end = t_end if t_final is None else float(t_final)
    rig = pip_rig(joint_friction, s)
    q_start = np.zeros(rig.num_joints)
    q_start[PIP] = q0
    op = rig.operating_point(pretension=pretension, joint_angles=q_start)
    loop = closed_loop(rig, make_controller(controller, rig, op=op), **get_entry(controller, rig).loop_options)
    ref = PerEntry([pip if j == PIP else Constant(0.0) for j in range(rig.num_joints)])
    log = ["joint_angle", "joint_velocity", "joint_angle_reference", "joint_angle_estimate", "applied_torque",
           "tendon_force", "state"] + (["joint_friction_torque"] if joint_friction else [])
    period = 1.0 / RATE_HZ
    res = simulate(loop, loop.create_context(op), t_end, inputs={"joint_angle_reference": ref}, log=log,
                   log_period=period, step=period / s.plant_substeps)
    friction = res["joint_friction_torque"][:, PIP] if joint_friction else np.zeros(res.t.size)
    return PipRun(controller, test, joint_friction, res.t, res["joint_angle"][:, PIP],
                  res["joint_angle_reference"][:, PIP], res["joint_angle_estimate"][:, PIP],
                  res["joint_velocity"][:, PIP], friction, res["applied_torque"], res["tendon_force"],
                  {k: res[k] for k in ("joint_angle", "joint_angle_estimate", "joint_friction_torque", "state")
                   if k in log})


def stuck_intervals(run: PipRun, speed: float) -> list[tuple[float, float]]:
    """``(start, duration)`` [s] of the intervals in which the PIP turns slower than ``speed`` [rad/s]."""
    still = np.abs(run.velocity) < speed
    edges = np.flatnonzero(np.diff(np.concatenate([[0], still.astype(int), [0]])))
    dt = run.t[1] - run.t[0]
    return [(float(run.t[a]), float((b - a) * dt)) for a, b in zip(edges[::2], edges[1::2])]


def pip_metrics(run: PipRun, study: PipStudy | None = None) -> dict:
    """Step: final error [rad] (mean over the last 0.1 s), rise time 10-90 % [s], overshoot [%]; sine: RMS error after
    the first period [rad]; both: the time the PIP stands (slower than the Stribeck velocity, the friction's static
    regime) while the reference moves (the sine) or after the step [s] and the longest such interval [s], peak
    |torque| [Nm], minimum tendon force [N]; the PIP's velocity reversals per second (``reversals_per_s``, counted
    where it turns faster than that) beside the reference's own (``reference_reversals_per_s``: 0 for the step, 2 f
    for the sine): reversals beyond the reference's are the stick-slip vibration of Fig 15.25."""
    from awiwi_drake.parameters.components import JointFrictionParams
    s = study or PipStudy()
    out = dict(peak_torque=float(np.max(np.abs(run.torque))), min_tendon_force=float(np.min(run.tendon_force)))
    e = run.q - run.reference
    dt = run.t[1] - run.t[0]
    dr = np.gradient(run.reference, dt)
    if run.test == "step":
        m = run.t >= s.step_time
        tail = run.t >= run.t[-1] - 0.1
        out["final_error"] = float(np.mean(np.abs(e[tail])))
        y = run.q[m] / s.step
        i10, i90 = np.argmax(y >= 0.1), np.argmax(y >= 0.9)
        out["rise_time"] = float(run.t[m][i90] - run.t[m][i10]) if np.any(y >= 0.9) else math.nan
        out["overshoot"] = float(max(0.0, 100 * (np.max(y) - 1)))
        moving = m
    else:
        after = run.t >= 1.0 / s.sine_frequency
        out["rms_error"] = float(np.sqrt(np.mean(e[after] ** 2))) if np.any(after) else math.nan
        moving = np.abs(dr) > 1e-9
    slow = JointFrictionParams().stribeck_velocity
    still = (np.abs(run.velocity) < slow) & moving
    out["still_time"] = float(np.sum(still) * dt)
    out["longest_still"] = max((d for t0, d in stuck_intervals(run, slow)), default=0.0)
    dur = float(np.sum(moving)) * dt

    def reversals(x):
        sgn = np.sign(x[moving & (np.abs(x) > slow)])
        return float(np.sum(sgn[1:] != sgn[:-1]) / dur) if dur > 0 and sgn.size > 1 else 0.0
    out["reversals_per_s"] = reversals(run.velocity)
    out["reference_reversals_per_s"] = reversals(dr)
    return out
