"""Thesis ch. 6: the wrist study of Fig 6.9-6.10 and the finger drift under wrist motion (results are data).

* :func:`wrist_motion_study` - Fig 6.9, 6.10: flexion then abduction of the wrist
  (:mod:`awiwi_drake.hand.wrist` kinematics): tendon displacements and constraint errors
  (:meth:`WristMotionResult.plot` draws them).
* :func:`wrist_compensation_study` - finger joint drift during a wrist
  abduction sweep, with and without the feedforward compensation ``-h_wrist / r_m`` ((6.9)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from awiwi_drake.analysis import PerEntry, Sine, rig_monitors, simulate
from awiwi_drake.control import closed_loop
from awiwi_drake.control.joint_pd import joint_pd_controller
from awiwi_drake.hand.diagrams import finger_diagram, hand_diagram
from awiwi_drake.hand.wrist import (TENDON_FINGERS, wrist_constraint_errors, wrist_kinematics, wrist_params,
                                    wrist_tendon_offsets)
from awiwi_drake.parameters.hand import JointControllerParams
from awiwi_drake.parameters.wrist import WristParams
from awiwi_drake.plotting import figure_axes, label_axes

__all__ = ["WristMotionResult", "wrist_motion_study", "FINGER_COLORS", "WristCompensationStudy",
           "wrist_compensation_study"]


@dataclass
class WristMotionResult:
    """Data of the thesis's wrist check (Fig 6.9, 6.10): flexion, then abduction.

    ``t`` [s]; ``wrist_angle`` (N, 2): [q71, q73] [rad]; ``offsets`` (N, num_tendons): tendon displacement
    ``h_wrist(q) - h_wrist(0)`` [m] (Fig 6.10); ``constraint_errors`` (N, 6): distance constraint errors [m]
    (Fig 6.9, in the order of :func:`wrist_constraint_errors`); ``phase``: ``"flexion"`` or ``"abduction"`` per
    sample; ``median_distance``: signed lateral distance ``y - b/2`` of each tendon's forearm point from the wrist's
    median axis [m]; ``flexion_peak``, ``abduction_peak``: largest |displacement| in each phase [m] (abduction:
    relative to the start of its phase); ``abduction_slope`` [m/m], ``abduction_intercept`` [m] and
    ``abduction_r2``: least-squares line of the abduction-induced displacement at the abduction peak against
    ``median_distance``, and its coefficient of determination.
    """

    t: np.ndarray
    wrist_angle: np.ndarray
    offsets: np.ndarray
    constraint_errors: np.ndarray
    phase: np.ndarray
    median_distance: np.ndarray
    flexion_peak: float = 0.0
    abduction_peak: float = 0.0
    abduction_slope: float = 0.0
    abduction_intercept: float = 0.0
    abduction_r2: float = 0.0
    fingers: tuple = field(default=TENDON_FINGERS)

    @property
    def max_constraint_error(self) -> float:
        """max over time and constraints of |error| [m] (Fig 6.9)."""
        return float(np.max(np.abs(self.constraint_errors)))

    @property
    def flexion_to_abduction_ratio(self) -> float:
        """flexion_peak / abduction_peak (small: flexion barely moves the tendons)."""
        return self.flexion_peak / self.abduction_peak

    def plot(self, ax=None, *, panel: str | None = None):
        """Fig 6.9 (``panel="constraint_errors"``: the largest distance-constraint error over time) and Fig 6.10
        (``panel="displacements"``: each tendon's displacement through the wrist, Table 6.2 order, coloured by
        finger, the flexion phase shaded, the abduction peak's proportionality fit written); both side by side
        when ``panel`` is None (``ax`` then two axes).  ``(fig, ax)``."""
        if panel is None:
            fig, ax = figure_axes(ax, ncols=2, figsize=(12, 4))
            self.plot(ax[0], panel="constraint_errors")
            self.plot(ax[1], panel="displacements")
            return fig, ax
        if panel not in ("constraint_errors", "displacements"):
            raise ValueError(f"WristMotionResult.plot: panel {panel!r} must be None, 'constraint_errors' or "
                             "'displacements'")
        fig, ax = figure_axes(ax, figsize=(7.0, 4.0))
        if panel == "constraint_errors":
            ax.plot(self.t, np.max(np.abs(self.constraint_errors), axis=1), color="k")
            label_axes(ax, "max constraint error [m]", xlabel="t [s]", legend=None,
                       title="max(|AA0|, |BB0|, |CC0|, |AB|, |AC|, |BC|) errors")
            ax.ticklabel_format(axis="y", style="sci", scilimits=(0, 0))
            return fig, ax
        seen = set()
        for i, finger in enumerate(self.fingers):
            ax.plot(self.t, self.offsets[:, i], color=FINGER_COLORS.get(finger, "k"), lw=0.9,
                    label=finger if finger not in seen else None)
            seen.add(finger)
        flex = self.phase == "flexion"
        if np.any(flex):
            ax.axvspan(self.t[flex][0], self.t[flex][-1], color="0.92", zorder=0)
        peak_q = np.degrees(np.max(np.abs(self.wrist_angle), axis=0))
        label_axes(ax, "tendon displacement [m]", xlabel="t [s]", legend=None,
                   title=f"wrist: flexion {peak_q[1]:.0f} deg (shaded), then abduction {peak_q[0]:.0f} deg")
        ax.text(0.99, 0.02,
                f"abduction peak vs distance from median axis: slope {self.abduction_slope:.3f} m/m, "
                f"R$^2$ = {self.abduction_r2:.4f}\nflexion/abduction peak ratio "
                f"{self.flexion_to_abduction_ratio:.2f}",
                transform=ax.transAxes, ha="right", va="bottom", fontsize=8)
        ax.legend(loc="upper left", fontsize=8)
        return fig, ax


def wrist_motion_study(*, flexion: float = math.radians(30.0), abduction: float = math.radians(20.0),
                       duration: float = 4.0, num_samples: int = 201, hold_flexion: bool = False,
                       params: WristParams | None = None) -> WristMotionResult:
    """Flexion, then abduction, as in the thesis's check (Fig 6.9, 6.10); a :class:`WristMotionResult`.

    The first half of ``duration`` [s] (Fig 6.10: 4 s; Fig 6.9: 10 s) moves q73 along
    ``flexion (1 - cos(2 pi s))/2`` (out to ``flexion`` and back), the second half moves q71 likewise to
    ``abduction`` (s the phase time / phase duration; thesis: 30 deg and 20 deg).  With ``hold_flexion=True`` q73
    ramps to ``flexion`` (``(1 - cos(pi s))/2``) and stays there during the abduction.  ``num_samples`` >= 5.
    The abduction statistics use the displacement caused by the abduction alone: offsets at the abduction peak minus
    offsets at the start of the abduction phase, fitted linearly against ``median_distance``.
    """
    if not (duration > 0.0):
        raise ValueError(f"duration must be > 0 [s], got {duration}")
    if int(num_samples) < 5:
        raise ValueError(f"num_samples must be >= 5, got {num_samples}")
    p = wrist_params(params)
    t = np.linspace(0.0, duration, int(num_samples))
    half = 0.5 * duration
    in_flex = t < half
    s = np.where(in_flex, t / half, (t - half) / half)
    bump = 0.5 * (1.0 - np.cos(2.0 * np.pi * s))
    if hold_flexion:
        q73 = np.where(in_flex, flexion * 0.5 * (1.0 - np.cos(np.pi * s)), flexion)
    else:
        q73 = np.where(in_flex, flexion * bump, 0.0)
    q71 = np.where(in_flex, 0.0, abduction * bump)
    offsets = np.empty((t.size, p.num_tendons))
    errors = np.empty((t.size, 6))
    for i in range(t.size):  # analysis loop over samples (not a system calc)
        offsets[i] = wrist_tendon_offsets(q71[i], q73[i], p)
        errors[i] = wrist_constraint_errors(wrist_kinematics(q71[i], q73[i], p), p)
    dist = p.forearm_offset_array[:, 1] - 0.5 * p.width
    start = int(np.argmax(~in_flex))
    abd = offsets[int(np.argmax(np.abs(q71)))] - offsets[start]
    slope, intercept = np.polyfit(dist, abd, 1)
    ss_res = float(np.sum((abd - (slope * dist + intercept)) ** 2))
    ss_tot = float(np.sum((abd - abd.mean()) ** 2))
    return WristMotionResult(
        t=t, wrist_angle=np.column_stack([q71, q73]), offsets=offsets, constraint_errors=errors,
        phase=np.where(in_flex, "flexion", "abduction"), median_distance=dist,
        flexion_peak=float(np.max(np.abs(offsets[in_flex]))),
        abduction_peak=float(np.max(np.abs(offsets[~in_flex] - offsets[start]))),
        abduction_slope=float(slope), abduction_intercept=float(intercept),
        abduction_r2=1.0 - ss_res / ss_tot)


#: One colour per finger for tendon plots.
FINGER_COLORS = {"thumb": "tab:red", "index": "tab:blue", "middle": "tab:green",
                 "ring": "tab:orange", "fifth": "tab:purple"}


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

    def plot(self, ax=None):
        """The finger joints' drift (those that move) without and with the wrist feedforward, side by side (``ax``:
        two axes); ``(fig, ax)``."""
        fig, ax = figure_axes(ax, ncols=2, figsize=(10, 3.5), sharey=True)
        for a, drift, title in ((ax[0], self.drift_uncompensated, "uncompensated"),
                                (ax[1], self.drift_compensated, "with wrist feedforward")):
            for j, name in enumerate(self.joint_names):
                if np.max(np.abs(drift[:, j])) > 1e-6:
                    a.plot(self.t, drift[:, j], label=name)
            label_axes(a, "q - q_ref [rad]" if a is ax[0] else "", legend=None, title=title)
        ax[0].legend(fontsize=7, ncol=2)
        return fig, ax


def wrist_compensation_study(target: str = "index", *, amplitude: float = np.radians(5.0), frequency: float = 2.0,
                             t_final: float = 0.5, controller: JointControllerParams | None = None,
                             accuracy: float = 1e-3, params=None) -> WristCompensationStudy:
    """Sweep the wrist abduction ``q71 = amplitude sin(2 pi frequency t)`` [rad] under joint control.

    The joint references stay at the operating point; the drift is the joint
    motion the wrist causes through the tendon path change (6.9).  Run once
    without and once with the feedforward ``-h_wrist / r_m``.  ``target`` is
    a finger name or ``"hand"`` (a fresh rig with ``wrist=True`` per run); ``params`` its
    ``FingerRigParams``/``HandRigParams`` (default: the defaults, thesis physics on).
    """
    drift, fmin, events = {}, {}, {}
    t_grid = np.linspace(0.0, t_final, 201)
    for comp in (False, True):
        rig = (hand_diagram(wrist=True, params=params) if target == "hand"
               else finger_diagram(finger=target, wrist=True, params=params))
        cl = closed_loop(rig, joint_pd_controller(rig, controller, wrist_compensation=comp))
        op = rig.operating_point()
        ctx = cl.create_context(op, references={"joint_angle_reference": op.joint_angle})
        res = simulate(cl.diagram, ctx, t_final, inputs={"wrist_angle": PerEntry([Sine(amplitude, frequency), 0.0])},
                       log=("joint_angle", "tendon_force"), monitors=rig_monitors(rig),
                       max_step=1.0 / cl.rate_hz, accuracy=accuracy)
        events[comp] = list(res.events)
        res = res.resample(t_grid)
        drift[comp] = res["joint_angle"] - op.joint_angle
        fmin[comp] = float(np.min(res["tendon_force"]))
    return WristCompensationStudy(t_grid, amplitude * np.sin(2 * np.pi * frequency * t_grid), drift[False],
                                  drift[True], list(rig.joint_names),
                                  {"uncompensated": fmin[False], "compensated": fmin[True]},
                                  {"uncompensated": events[False], "compensated": events[True]})
