"""Thesis ch. 5: numerical studies on the finger models (results are data).

* :func:`coriolis_study` - Fig 5.7: release a 0.1 rad deflection of the second
  joint (MCP flexion, abduction at 0) with the motors fixed, with and without
  the Coriolis/centrifugal terms.
* :func:`coupling_hold_study` - the ring/fifth PIP/DIP coupling element holds
  ``q_DIP = (r_x3/r_x2) q_PIP`` during a controlled PIP motion.
* :func:`thumb_estimation_study` - Fig 5.16-5.17: Algorithm 1 (thumb base estimation,
  :mod:`awiwi_drake.hand.estimation`) on a grid of poses, per iterations, noise and start.

``plot_*`` draw the results (data in, ``(fig, ax)`` out).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, Demultiplexer

from awiwi_drake.analysis.simulate import simulate
from awiwi_drake.components.routing import TendonRouting_
from awiwi_drake.components.spring import SpringBank_, tendon_spring
from awiwi_drake.control import closed_loop
from awiwi_drake.control.joint_pd import joint_pd_controller
from awiwi_drake.hand.coupling import ThumbCoupling, finger_coupling
from awiwi_drake.hand.estimation import noise_error_bound, thumb_base_gradient_search
from awiwi_drake.hand.diagrams import finger_diagram
from awiwi_drake.hand.plant import add_applied_force_sum, coupling_force_gain, make_finger_plant
from awiwi_drake.hand.systems import CoriolisCancellation
from awiwi_drake.parameters.hand import FingerRigParams, JointControllerParams
from awiwi_drake.plotting import figure_axes, label_axes, plot_traces

__all__ = ["CoriolisStudy", "coriolis_study", "mcp_flexion_joint", "fixed_motor_diagram",
           "CouplingHoldStudy", "coupling_hold_study",
           "EstimationStudy", "thumb_estimation_study"]


def fixed_motor_diagram(finger: str = "index", params: FingerRigParams | None = None, *,
                        coriolis: bool = True):
    """Finger plant + routing + springs with the motors held at their pretension angles.

    With ``coriolis=False`` a :class:`CoriolisCancellation_` adds ``C(q, v) v``
    to the applied generalised force, removing the Coriolis/centrifugal terms
    from ``M vdot + C v = tau`` (the simplified model of Fig 5.7).
    Returns ``(diagram, plant)``; the diagram exports the input
    ``external_torque`` (n) [N m] (fix it before simulating) and the
    outputs ``state`` (plant [q; v]) and ``tendon_force``.
    """
    p = params if params is not None else FingerRigParams.for_finger(finger)
    b = DiagramBuilder()
    plant, model = make_finger_plant(finger, p.finger, builder=b, gravity=p.gravity)
    n = plant.num_positions()
    coupling = finger_coupling(finger, p.finger)
    m = coupling.num_tendons
    spring = tendon_spring(p.spring)
    x_pre = float(np.ravel(spring.inverse_force(np.array([p.pretension])))[0])
    routing = b.AddNamedSystem("routing", TendonRouting_[float](coupling, p.motor.pulley_radius, np.full(m, x_pre)))
    springs = b.AddNamedSystem("springs", SpringBank_[float](spring, m))
    motors = b.AddNamedSystem("motors_fixed", ConstantVectorSource(np.zeros(m)))
    split = b.AddNamedSystem("plant_state_split", Demultiplexer([n, n]))
    b.Connect(plant.get_state_output_port(), split.get_input_port())
    b.Connect(motors.get_output_port(), routing.GetInputPort("motor_angle"))
    b.Connect(split.get_output_port(0), routing.GetInputPort("joint_angle"))
    b.Connect(routing.GetOutputPort("elongation"), springs.GetInputPort("elongation"))
    b.Connect(springs.GetOutputPort("tendon_force"), routing.GetInputPort("tendon_force"))
    sources = [routing.GetOutputPort("generalized_force")]
    if not coriolis:
        standalone, _ = make_finger_plant(finger, p.finger, gravity=p.gravity)
        cc = b.AddNamedSystem("coriolis_cancellation", CoriolisCancellation(standalone))
        b.Connect(plant.get_state_output_port(), cc.get_input_port(0))
        sources.append(cc.get_output_port(0))
    add_applied_force_sum(b, plant, sources, coupling_force_gain(plant, model))
    b.ExportOutput(plant.get_state_output_port(), "state")
    b.ExportOutput(springs.GetOutputPort("tendon_force"), "tendon_force")
    diagram = b.Build()
    diagram.set_name(f"{finger}_fixed_motors" + ("" if coriolis else "_no_coriolis"))
    return diagram, plant


@dataclass
class CoriolisStudy:
    """Fig 5.7: joint trajectories with/without Coriolis terms and their difference.

    ``difference`` = ``q_full - q_simplified`` (T x n) [rad] on the common grid ``t``.
    """

    t: np.ndarray
    q_full: np.ndarray
    q_simplified: np.ndarray
    joint_names: list

    @property
    def difference(self) -> np.ndarray:
        return self.q_full - self.q_simplified

    @property
    def max_abs_difference(self) -> np.ndarray:
        """Per joint [rad] (thesis: below 1e-3 rad over 0.2 s)."""
        return np.max(np.abs(self.difference), axis=0)

    def plot(self, ax=None):
        """Fig 5.7: joint position difference full minus simplified (no Coriolis) model; ``(fig, ax)``."""
        return plot_traces(self.t, dict(zip(self.joint_names, self.difference.T)), ylabel="position error [rad]",
                           ax=ax, legend=dict(fontsize=8))


def mcp_flexion_joint(finger: str) -> int:
    """Plant joint index of the finger's first flexion joint (the "second joint" of Fig 5.7).

    index/middle/ring: 1 (``q_x1``, after the abduction ``q_x0``); fifth: 2
    (after the HMC ``q_5h`` and ``q_50``); thumb: 0 (base flexion ``q10``).
    """
    return {"thumb": 0, "fifth": 2}.get(finger, 1)


def coriolis_study(finger: str = "index", *, deflection: float = 0.1, joint: int | None = None,
                   t_final: float = 0.2, params: FingerRigParams | None = None,
                   accuracy: float = 1e-7, num_samples: int = 401) -> CoriolisStudy:
    """Release a ``deflection`` [rad] of ``joint`` with the motors fixed (Fig 5.7).

    Default ``joint``: the MCP flexion (:func:`mcp_flexion_joint`, 1 for the
    index), as in the thesis: "initially deflected 0.1 rad in the second joint
    (flexion)", the first joint (abduction) at 0.
    Integrated with Drake's error-controlled ``runge_kutta5`` at ``accuracy``
    (the result agrees with ``runge_kutta3`` at 1e-6 to 1e-8 rad).
    """
    p = params if params is not None else FingerRigParams.for_finger(finger)
    out = {}
    names = None
    for flag in (True, False):
        diagram, plant = fixed_motor_diagram(finger, p, coriolis=flag)
        n = plant.num_positions()
        names = [plant.get_joint(j).name() for j in plant.GetJointIndices()]
        j = mcp_flexion_joint(finger) if joint is None else joint
        if not 0 <= j < n:
            raise ValueError(f"coriolis_study: joint index {j} out of range 0..{n - 1} ({', '.join(names)})")
        ctx = diagram.CreateDefaultContext()
        diagram.GetInputPort("external_torque").FixValue(ctx, np.zeros(n))
        x0 = np.zeros(2 * n)
        x0[j] = deflection
        if getattr(p.finger, "pip_dip_coupled", False) and j == n - 2:   # coupled: deflect the DIP consistently
            x0[n - 1] = deflection * p.finger.dip_pip_ratio                # (no coupling-element transient)
        ctx.SetContinuousState(x0)
        res = simulate(diagram, ctx, t_final, log=("state",), integrator="runge_kutta5", max_step=1e-3,
                       accuracy=accuracy)
        out[flag] = res.resample(np.linspace(0.0, t_final, num_samples))
    t = out[True].t
    return CoriolisStudy(t, out[True]["state"][:, : len(names)], out[False]["state"][:, : len(names)], names)


@dataclass
class CouplingHoldStudy:
    """PIP step of a coupled finger under joint control: coupling error ``q_DIP - c q_PIP``; ``final_state``: the
    plant's state at the end (its friction states decide where the joints rest)."""

    t: np.ndarray
    q_pip: np.ndarray
    q_dip: np.ndarray
    ratio: float
    final_state: np.ndarray

    @property
    def coupling_error(self) -> np.ndarray:
        return self.q_dip - self.ratio * self.q_pip

    @property
    def max_coupling_error(self) -> float:
        return float(np.max(np.abs(self.coupling_error)))

    def plot(self, ax=None):
        """PIP, DIP and the coupling error q_DIP - c q_PIP during the PIP step; ``(fig, ax)``."""
        return plot_traces(self.t, {"q_PIP": self.q_pip, "q_DIP": self.q_dip, "q_DIP - c q_PIP": self.coupling_error},
                           ylabel="[rad]", ax=ax, legend=dict(fontsize=8))


def coupling_hold_study(finger: str = "ring", *, pip_step: float = 0.5, t_final: float = 0.3,
                        controller: JointControllerParams | None = None) -> CouplingHoldStudy:
    """Step the PIP reference of a coupled finger by ``pip_step`` [rad] and log PIP/DIP."""
    rig = finger_diagram(finger=finger)
    fp = rig.params.finger
    if not getattr(fp, "pip_dip_coupled", False):
        raise ValueError(f"coupling_hold_study: finger {finger!r} has no PIP/DIP coupling")
    cl = closed_loop(rig, joint_pd_controller(rig, controller))
    n = rig.num_joints
    q_ref = np.zeros(n)
    q_ref[n - 2] = pip_step
    q_ref[n - 1] = pip_step * fp.dip_pip_ratio
    ctx = cl.create_context(rig.operating_point(), references={"joint_angle_reference": q_ref})
    res = simulate(cl.diagram, ctx, t_final, log=("joint_angle", "state"), max_step=1.0 / cl.rate_hz, accuracy=1e-4)
    q = res["joint_angle"]
    return CouplingHoldStudy(res.t, q[:, n - 2], q[:, n - 1], fp.dip_pip_ratio, res["state"][-1])


@dataclass
class EstimationStudy:
    """Fig 5.16-5.17 study: grid truth, estimates and errors per (iterations, noise, start)."""

    grid: np.ndarray                # (N, 2) true (q10, q11)
    estimates: dict                 # (iterations, noise [m], start) -> (N, 2)
    errors: dict                    # same keys -> (N,) |q_hat - q| [rad]
    bounds: dict                    # same keys -> (N,) first-order noise bound + final step
    at_limit: dict = None           # same keys -> (N,) bool: the estimate sits on the +-pi/2 projection bound

    def summary_rows(self) -> list[dict]:
        """One row per case: iterations, noise [mm], start, mean/median/max error [rad]."""
        rows = []
        for key, e in self.errors.items():
            it, a, start = key
            rows.append(dict(iterations=it, noise_mm=1e3 * a, start=start, mean=float(np.mean(e)),
                             median=float(np.median(e)), max=float(np.max(e)),
                             frac_within_0p1=float(np.mean(e < 0.1)),
                             at_limit=int(np.sum(self.at_limit[key])) if self.at_limit else 0))
        return rows

    def plot(self, start: str = "cold", *, case: tuple | None = None, ax=None):
        """Fig 5.17: one panel per case of ``start`` (rows 50/30/15 iterations, columns 0/0.5/1 mm noise), each the
        true (q10, q11) grid (red circles) and the estimates (blue crosses); ``case`` ``(iterations, noise [m],
        start)``: that case alone on ``ax`` (Fig 5.16).  ``(fig, axes)``."""
        if case is None:
            its = sorted({k[0] for k in self.estimates}, reverse=True)
            noises = sorted({k[1] for k in self.estimates})
            fig, axes = figure_axes(None, nrows=len(its), ncols=len(noises), figsize=(3 * len(noises), 3 * len(its)),
                                    squeeze=False)
            for i, it in enumerate(its):
                for j, a in enumerate(noises):
                    self.plot(case=(it, a, start), ax=axes[i, j])
            fig.tight_layout()
            return fig, axes
        if case not in self.estimates:
            raise ValueError(f"EstimationStudy.plot: case {case!r} was not run; run: {sorted(self.estimates)}")
        fig, ax = figure_axes(ax, figsize=(4, 4))
        est = self.estimates[case]
        ax.plot(self.grid[:, 0], self.grid[:, 1], "o", mfc="none", mec="r", ms=5, label="true")
        ax.plot(est[:, 0], est[:, 1], "x", color="b", ms=4, label="estimate")
        it, a, start = case
        label_axes(ax, "q11 [rad]", xlabel="q10 [rad]", legend=None)
        ax.set_title(f"{it} it., {1e3 * a:g} mm, {start}", fontsize=9)
        ax.set_xlim(-1.8, 1.8)
        ax.set_ylim(-1.8, 1.8)
        ax.set_aspect("equal")
        return fig, ax


def thumb_estimation_study(coupling: ThumbCoupling | None = None, *, n_grid: int = 13,
                           limit: float = 1.5, iterations=(15, 30, 50), noise=(0.0, 5e-4, 1e-3),
                           starts=("cold", "warm"), step0: float = 0.1, seed: int = 0) -> EstimationStudy:
    """Reproduce Fig 5.16-5.17 on an ``n_grid`` x ``n_grid`` grid over ``[-limit, limit]^2``.

    Noise: uniform in ``[-a, a]`` on each base tendon length ("amplitude").
    Cold start: every estimate starts at (0, 0) (the thesis's evaluation).
    Warm start: the grid is visited in a serpentine order and each estimate
    starts from the previous estimate (the thesis's real-time use); the first
    one starts at the true first grid point (an estimator initialised at a
    known pose, e.g. after homing).
    """
    coupling = coupling or ThumbCoupling()
    if n_grid < 2:
        raise ValueError(f"n_grid must be >= 2, got {n_grid}")
    axis = np.linspace(-limit, limit, n_grid)
    grid = np.array([(a, b if i % 2 == 0 else -b) for i, a in enumerate(axis) for b in axis])
    h0 = coupling.h(np.zeros(4))[:4]
    dh_true = np.array([coupling.h(np.array([a, b, 0, 0]))[:4] - h0 for a, b in grid])
    rng = np.random.default_rng(seed)
    noise_unit = rng.uniform(-1.0, 1.0, size=dh_true.shape)
    sig_bound = np.array([noise_error_bound(coupling, g, 1.0) for g in grid])
    est, err, bnd, lim = {}, {}, {}, {}
    for a in noise:
        meas = dh_true + a * noise_unit
        for it in iterations:
            for start in starts:
                if start not in ("cold", "warm"):
                    raise ValueError(f"starts: expected 'cold' or 'warm', got {start!r}")
                q_prev = grid[0].copy()
                out = np.zeros_like(grid)
                steps = np.zeros(len(grid))
                hit = np.zeros(len(grid), dtype=bool)
                for k, m in enumerate(meas):
                    q0 = (0.0, 0.0) if start == "cold" else q_prev
                    r = thumb_base_gradient_search(coupling, m, q0, iterations=it, step0=step0)
                    out[k], steps[k], q_prev, hit[k] = r.q, r.step, r.q, r.at_limit
                est[(it, a, start)] = out
                lim[(it, a, start)] = hit
                err[(it, a, start)] = np.linalg.norm(out - grid, axis=1)
                bnd[(it, a, start)] = a * sig_bound + 2.0 * steps
    return EstimationStudy(grid=grid, estimates=est, errors=err, bounds=bnd, at_limit=lim)
