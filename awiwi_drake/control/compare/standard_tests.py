"""The standard closed-loop tests, their default parameters, and the comparison of controllers.

:func:`run_standard_tests` runs, on one :class:`~awiwi_drake.control.base.ClosedLoop`,

* ``step``: reference step ``r0 -> r0 + step`` (rise time 10-90 %, overshoot,
  settling time in ``settling_band`` (2 %; 5 % on the noisy tendon rig), steady-state
  error, damping ratio of a fitted 2nd-order model);
* ``sine``: sinusoidal tracking (RMS error, gain and phase at the frequency);
* ``disturbance``: an ``external_torque`` step at constant reference
  (achieved stiffness ``dtau / dq``; link rigs only; on fingers and the hand sized per DoF above the friction
  observer's bound and inside the design's linear range, :func:`size_loads`, the measured stiffness checked against
  the design's, :func:`load_stiffness_range`);
* ``sweep``: a linear chirp of the reference, gain diagram ``|Y/R|(f)`` on log-spaced
  frequencies (as in Fig 11.4); the -3 dB bandwidth comes from the loop's linearisation
  where Drake can linearise it (continuous loops), else from the chirp
  (``Metrics.bandwidth_source``);

and :func:`compare` does so for several controllers and returns a
:class:`Comparison` (runs + :class:`~awiwi_drake.control.compare.metrics.MetricsTable`).
Each test starts from the closed loop settled at the initial reference.
"""


from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from awiwi_drake.analysis import PHYSICAL_FAILURES, Chirp, Constant, PerEntry, Sine, Step, simulate
from awiwi_drake.control.base import ClosedLoop, closed_loop
from awiwi_drake.control.compare.metrics import (Metrics, MetricsTable, disturbance_metrics, gain_diagram,
                                                 linear_bandwidth, sine_metrics, step_metrics, sweep_metrics)
from awiwi_drake.control.compare.channels import joint_channels, joint_inputs
from awiwi_drake.control.compare.runner import TestRun, applied_port, settle, torque_limit
from awiwi_drake.control.design import ControllerDesign
from awiwi_drake.control.registry import get_entry, make_controller, rig_kind
from awiwi_drake.parameters.control import CompareTestParams
from awiwi_drake.rigs.base import Rig

__all__ = ["TESTS", "compare_test_params", "default_tests", "Comparison", "run_test", "run_joint_test", "flag_run",
           "stopped_row", "run_standard_tests", "compare", "build_loops", "dominant_time_constant",
           "design_time_constant", "design_step_duration", "short_test_params",
           "compare_controllers", "factory_options", "observer_at_bound", "mark_dead_band", "mark_load",
           "design_stiffness", "size_loads", "load_stiffness_range"]

TESTS = ("step", "sine", "disturbance", "sweep")


# output of a loop whose controller contains the force distribution (ch. 7): 0 ok, 1 infeasible, 2 bounds
DISTRIBUTION_STATUS = "controller_distribution_status"
ESTIMATION_ERROR = "joint_angle_estimation_error"
# the ch. 9 observer's compensation and its friction bound (per DoF) in a chain controller
OBSERVER_COMPENSATION = "controller_friction_compensation"
OBSERVER_BOUND = "controller_friction_compensation_bound"


def observer_at_bound(compensation, bound) -> bool:
    """True when the observer's compensation sits at its (non-zero) friction bound on every sample given (the end of
    a run): the link-side torque it estimates exceeds what the guides' friction can be, i.e. a load it leaves to the
    impedance (:class:`~awiwi_drake.control.joint_stage.JointFrictionObserver_`)."""
    c, b = np.abs(np.asarray(compensation, float)), np.asarray(bound, float)
    return bool(c.size) and bool(np.all((b > 0.0) & (c >= b * (1.0 - 1e-9))))

def compare_test_params(rig: Any, **overrides: Any) -> CompareTestParams:
    """Default standard tests for a rig kind (tendon force in N, link angle in rad)."""
    kind = rig_kind(rig)
    if kind == "tendon-rig":
        base = CompareTestParams(initial_reference=10.0, step_size=5.0, step_duration=0.25, sine_amplitude=2.0,
                                 sine_frequency=5.0, sweep_amplitude=1.0, sweep_start=1.0, sweep_stop=60.0,
                                 sweep_duration=2.0, settle_time=0.2, settling_band=0.05)
    elif kind in ("finger", "hand"):
        # per DoF, relative to the operating point [rad]; chosen: a 0.2 rad (11 deg) step (Fig 15.24 steps the
        # PIP by ~25 deg); the load of a loop with a bounded friction observer sized per DoF (load_bound_factor 3 x
        # its bound, at most a step's deflection at its designed stiffness: size_loads), of the others 0.01 Nm
        # (0.02 rad at the chosen 0.5 Nm/rad impedance, Fig 15.22's soft setting on the single-joint testbed);
        # 0.3 s chosen (the CLI lengthens it where the compared designs need more: design_step_duration); no sweep
        # by default (Fig 15.26 is the joint rig's)
        base = CompareTestParams(step_size=0.2, step_duration=0.3, sine_amplitude=0.1, sine_frequency=2.0,
                                 sine_periods=2.0, settle_time=0.05, disturbance_torque=0.01, load_bound_factor=3.0)
    else:
        base = CompareTestParams()
    return base.replace(**overrides) if overrides else base


@dataclass
class Comparison:
    """Result of :func:`compare`: all runs and the metrics table."""

    runs: list[TestRun]
    table: MetricsTable
    rig: str = ""

    def run(self, controller: str, test: str) -> TestRun:
        for r in self.runs:
            if r.controller == controller and r.test == test:
                return r
        raise KeyError(f"no run for controller {controller!r} and test {test!r}")


def dominant_time_constant(loop: ClosedLoop, params: CompareTestParams | None = None, *,
                           min_share: float = 0.01) -> float | None:
    """``1 / sigma`` [s] of the slowest closed-loop pole that matters for tracking, or None.

    The loop (continuous: ``rate_hz=None``) is linearised with Drake's ``Linearize``
    from its first reference to its tracked output at the settled start; each
    pole's share of the DC gain is ``|c_i b_i / lambda_i|`` in modal coordinates (norms over the entries of
    a vector reference and output, e.g. every joint of a finger),
    and poles with less than ``min_share`` of the total (e.g. a co-contraction
    mode that the link angle does not see) are ignored.  Sampled loops or loops
    with discrete controller state (which ``Linearize`` cannot take in a mixed
    diagram) return their controller's designed tracking time constant
    (:func:`design_time_constant`) or None; unstable loops return None.
    """
    from awiwi_drake.analysis import linearize

    p = params or compare_test_params(loop.rig)
    ctx = settle(loop, p.initial_reference, t_settle=0.0, max_step=p.max_step)
    if not ctx.has_only_continuous_state():
        return design_time_constant(loop)
    try:
        lin = linearize(loop.diagram, context=ctx, input=loop.references[0], outputs=(loop.tracked_outputs[0],),
                        equilibrium_tolerance=None)
    except ValueError:
        return design_time_constant(loop)
    lam, V = np.linalg.eig(lin.A)
    try:
        W = np.linalg.inv(V)
    except np.linalg.LinAlgError:
        return None
    # each mode's part of the DC gain C V diag(1/lambda) W B: |C v_i| |w_i B| / |lambda_i| (vector references and
    # outputs, e.g. every joint of a finger: norms over them)
    share = (np.linalg.norm(lin.C @ V, axis=0) * np.linalg.norm(W @ lin.B, axis=1)
             / np.abs(np.where(np.abs(lam) > 1e-12, lam, 1e-12)))
    if not np.all(np.isfinite(share)) or share.sum() == 0 or np.any(lam.real >= 0):
        return None
    keep = share / share.sum() > min_share
    return float(1.0 / np.min(-lam.real[keep]))


def _design(loop: ClosedLoop) -> ControllerDesign | None:
    """The controller's :class:`~awiwi_drake.control.design.ControllerDesign` (its own or its law's; None without)."""
    ctrl = loop.controller
    for design in (getattr(ctrl, "design", None), getattr(getattr(ctrl, "law", None), "design", None)):
        if isinstance(design, ControllerDesign):
            return design
    return None


def mark_dead_band(rows: Sequence[Metrics], errors, hold, dof_load=None) -> None:
    """Flag each row ``stopped within friction dead band (X % of its bound)`` whose DoF is not settled while the run's
    end errors ``errors`` (k, output - reference per DoF) are a rest of the loop held by friction: ``hold(errors,
    dof_load)`` (the controller's ``design.friction_hold``, the closed form of its rest equations: the fraction
    of each DoF's friction bound the rest needs) is <= 1 on every DoF of the finger.  Physics, not a failure of the
    law: the frictions (4.1) and the lever's hysteresis hold the link there (ch. 9, ch. 11)."""
    frac = np.asarray(hold(np.asarray(errors, float), dof_load), float)
    for j, row in enumerate(rows):
        if "not settled" in row.flags and frac[j] <= 1.0:
            row.flags = "; ".join((row.flags, f"stopped within friction dead band ({100 * frac[j]:.0f} % of its "
                                              "bound)"))


def design_stiffness(loop: ClosedLoop) -> np.ndarray | None:
    """The static stiffness [Nm/rad] per DoF that the loop's design promises to a constant load on that DoF alone:
    ``1 / (K^-1)_jj`` of the design's stiffness matrix ``K`` (the other DoF held at their references by their own
    laws): the chain designs' decoupled :attr:`~awiwi_drake.control.joint_design.JointDesign.static_stiffness`, the
    15.5 finger backstepping's ``Kp`` (``design.Kp``; with the load observed its rest is ``Kp e = S^T tau_ext``,
    :class:`~awiwi_drake.control.finger_backstepping.ObservedBacksteppingController`); None when it reports none."""
    design = _design(loop)
    return None if design is None else design.static_stiffness


def size_loads(params: CompareTestParams, stiffness, bound) -> tuple[np.ndarray, list[str]]:
    """The load step [Nm] per DoF of a loop with a bounded (9.2) friction observer, and per DoF a note ("" or why the
    load is not above its bound).

    Above the bound: the observer compensates a link-side torque up to its bound ``B`` (``bound``, per DoF, the
    :func:`~awiwi_drake.components.friction.joint_friction_bound` it clips with) and the frictions it bounds hold up
    to another ``B`` at rest, so ``L_lo = load_bound_factor x B``.  Linear: the design's deflection ``L / K``
    (``stiffness`` ``K``, :func:`design_stiffness`) at most ``load_linear_fraction x |step_size|``, so
    ``L_hi = load_linear_fraction |step_size| K``.  The load is ``L_lo`` when ``0 < L_lo <= L_hi``, else ``L_hi``:
    a DoF without friction (``B = 0``) takes the largest linear load, and a DoF whose impedance is too soft for
    its friction (``L_lo > L_hi``) keeps the linear one and its note says so (the row is flagged with it)."""
    K, B = np.asarray(stiffness, dtype=float), np.asarray(bound, dtype=float)
    lo = params.load_bound_factor * B
    hi = params.load_linear_fraction * abs(params.step_size) * K
    load = np.where((lo > 0) & (lo <= hi), lo, hi)
    notes = ["" if lo[j] <= hi[j] else
             f"load {hi[j]:.3g} Nm kept linear ({params.load_linear_fraction:g} x the {abs(params.step_size):g} rad "
             f"step at the designed {K[j]:.3g} Nm/rad): {params.load_bound_factor:g} x its friction bound "
             f"{B[j]:.3g} Nm would deflect it {lo[j] / K[j]:.3g} rad" for j in range(K.size)]
    return load, notes


def load_stiffness_range(load: float, bound: float, stiffness: float,
                         estimation_error: float = 0.0) -> tuple[float, float]:
    """``(low, high)`` [Nm/rad]: the measured stiffness ``L / e`` of a DoF (design stiffness ``K``) under the load
    ``L`` with a friction observer bounded by ``B`` (``bound``, at the rest's tendon forces) and an estimator error
    of at most ``estimation_error`` ``eps`` [rad] (0 with ideal sensors).

    At rest the loop balances on its estimate ``e_hat``: ``K e_hat = L - h - c``, ``h`` the torque the bounded
    frictions hold (``|h| <= B``: the observer's bound is the most they can carry) and ``c = clip(L - h, -B, B)``
    the observer's compensation of what the tendons' torque does not explain, so ``K e_hat = max(L - h - B, 0)``,
    between ``max(L - 2B, 0)`` and ``L``; the true deflection differs from ``e_hat`` by the estimator's error before
    and after the load, ``|de| <= 2 eps``.  Hence ``e`` in ``[max(L - 2B, 0) / K - 2 eps, L / K + 2 eps]`` and
    ``L / e`` in ``[L / (L / K + 2 eps), L / (max(L - 2B, 0) / K - 2 eps)]`` (``high`` infinite when the lower
    deflection is not positive: a load within ``2B`` can be held whole)."""
    eps = 0.0 if not math.isfinite(estimation_error) else abs(float(estimation_error))
    L, B, K = abs(float(load)), float(bound), float(stiffness)
    e_lo = max(L - 2.0 * B, 0.0) / K - 2.0 * eps
    return L / (L / K + 2.0 * eps), (L / e_lo if e_lo > 0 else math.inf)


def mark_load(row: Metrics, params: CompareTestParams, bound: float, impedance: float | None = None,
              note: str = "") -> None:
    """Flag a load row (``row.load_torque`` ``L``) of a loop whose (9.2) observer clips at its friction bound
    ``bound`` ``B`` [Nm] (:class:`~awiwi_drake.control.joint_stage.JointFrictionObserver_`, at the end of the run);
    ``impedance`` the design's static stiffness ``K`` of the DoF [Nm/rad] (:func:`design_stiffness`), ``note``
    :func:`size_loads`'s.

    ``|L| < B``: the observer, link-side and driven by the measured tendon forces' torque, cannot tell such a load from
    the guides' friction and cancels it (9.1): the row's ``stiffness`` is NaN (a load over a deflection of ~0), and its
    ``negative stiffness`` / ``not settled`` (unless it drifts beyond the band of ``L / K``) become ``load held by the
    friction observer``.  ``|L| >= B``: the measured stiffness must lie in :func:`load_stiffness_range`, else
    ``stiffness off its design``."""
    load = row.load_torque if math.isfinite(row.load_torque) else params.disturbance_torque
    row.friction_bound = float(bound)
    if impedance is not None:
        row.design_stiffness = float(impedance)
    flags = [f for f in row.flags.split("; ") if f]
    if abs(load) < bound:
        still = impedance is not None and row.drift > params.settling_band * abs(load / impedance)
        flags = [f for f in flags if f != "negative stiffness" and (f != "not settled" or still)]
        flags.append(f"load held by the friction observer ({abs(load):.3g} Nm within its bound {bound:.3g} Nm)")
        row.stiffness = math.nan  # load / ~0: no deflection to measure (e.g. -1.4e14 Nm/rad), the flag says why
    elif impedance is not None:
        lo, hi = load_stiffness_range(load, bound, impedance, row.estimation_error)
        if not lo <= row.stiffness <= hi:
            flags.append(f"stiffness off its design ({row.stiffness:.3g} Nm/rad against {impedance:.3g}: expected "
                         f"{lo:.3g}-{hi:.3g} from its friction bound {bound:.3g} Nm and the estimator's error)")
    if note:
        flags.append(note)
    row.flags = "; ".join(flags)
    if flags and row.status == "ok":
        row.status = "flagged"


def design_time_constant(loop: ClosedLoop) -> float | None:
    """The controller's own slowest designed tracking time constant [s] (``design.time_constant`` of the
    controller or of its law: the finger/hand per-joint designs,
    :meth:`~awiwi_drake.control.joint_design.JointDesign.tracking_time_constant`, and the finger
    backstepping's joint modes), or None when it reports none."""
    design = _design(loop)
    tau = None if design is None else design.time_constant
    return float(tau) if tau is not None and math.isfinite(tau) and tau > 0 else None


def _linearized_bandwidth(loop: ClosedLoop, ctx) -> float | None:
    """-3 dB bandwidth [Hz] of the loop linearised (Drake ``Linearize``) at the settled context ``ctx``,
    from its first reference to its tracked output; None for loops ``Linearize`` cannot take (sampled
    or discrete controller state) or that are not asymptotically stable there (then the chirp decides)."""
    from awiwi_drake.analysis import linearize

    if loop.rate_hz or not ctx.has_only_continuous_state():
        return None
    try:
        lin = linearize(loop.diagram, context=ctx.Clone(), input=loop.references[0],
                        outputs=(loop.tracked_outputs[0],), equilibrium_tolerance=None)
    except ValueError:
        return None
    if lin.A.shape[0] == 0 or np.any(np.linalg.eigvals(lin.A).real >= 0):
        return None
    bw = linear_bandwidth(lin)
    return bw if math.isfinite(bw) else None


def _sample_dt(loop: ClosedLoop, params: CompareTestParams) -> float:
    return 1.0 / loop.rate_hz if loop.rate_hz else params.sample_period


def _schedule(test: str, p: CompareTestParams, r0: float):
    """``(reference schedule, run length [s])`` of ``test`` from the start reference ``r0``."""
    if test == "step":
        return Step(p.step_delay, r0 + p.step_size, before=r0), p.step_duration
    if test == "sine":
        return Sine(p.sine_amplitude, p.sine_frequency, offset=r0), p.sine_periods / p.sine_frequency
    if test == "disturbance":
        return Constant(r0), p.step_duration
    return Chirp(p.sweep_amplitude, p.sweep_start, p.sweep_stop, p.sweep_duration, offset=r0), p.sweep_duration


def _set_test_metrics(row: Metrics, test: str, p: CompareTestParams, t, r, y, r0: float):
    """Set ``test``'s metrics on ``row`` from one DoF's reference ``r`` and output ``y`` at the times ``t`` (the load
    test's ``row.load_torque`` set before); the sweep returns its gain diagram ``(f, g)``."""
    diagram = None
    if test == "step":
        values = step_metrics(t, y, r0, r0 + p.step_size, p.step_delay, band=p.settling_band, fit=True)
    elif test == "sine":
        skip = t >= 1.0 / p.sine_frequency  # drop the first period (transient)
        values = sine_metrics(t[skip], r[skip], y[skip], p.sine_frequency)
    elif test == "disturbance":
        values = disturbance_metrics(t, y, r0, p.step_delay, row.load_torque)
    else:
        diagram = gain_diagram(t, r, y, p.sweep_start, p.sweep_stop)
        values = dict(sweep_metrics(*diagram), bandwidth_source="chirp")
    for k_, v in values.items():
        setattr(row, k_, v)
    return diagram


def run_test(loop: ClosedLoop, test: str, *, controller: str = "controller",
             params: CompareTestParams | None = None, settled=None) -> tuple[TestRun, Metrics]:
    """Run one standard test (``step``, ``sine``, ``disturbance``, ``sweep``) on a closed loop."""
    if test not in TESTS:
        raise ValueError(f"unknown test {test!r}; known: {', '.join(TESTS)}")
    if not loop.references:
        raise ValueError(f"controller {controller!r} has no *_reference input: cannot run {test!r}")
    p = params or compare_test_params(loop.rig)
    if test == "disturbance" and "external_torque" not in loop.disturbances:
        raise ValueError(f"test 'disturbance' needs a rig input 'external_torque'; rig "
                         f"{getattr(loop.rig, 'name', '?')!r} has none")
    dt = _sample_dt(loop, p)
    r0 = p.initial_reference
    ctx = (settled.Clone() if settled is not None else settle(loop, r0, t_settle=p.settle_time, max_step=p.max_step))
    ctx.SetTime(0.0)
    meta: dict[str, Any] = {}
    ref, t_final = _schedule(test, p, r0)
    if test == "sweep":
        meta.update(f_low=p.sweep_start, f_high=p.sweep_stop)
        lin_bw = _linearized_bandwidth(loop, ctx)
    inputs = {r: ref for r in loop.references}
    if "external_torque" in loop.disturbances:
        inputs["external_torque"] = Step(p.step_delay, p.disturbance_torque) if test == "disturbance" else 0.0
    y = loop.tracked_outputs[0]
    slack = isinstance(loop.rig, Rig) and loop.rig.tension_only and loop.diagram.HasOutputPort("tendon_force")
    extra = {"external_torque": "external_torque" in inputs, "tendon_force": slack and y != "tendon_force",
             "applied_torque": loop.diagram.HasOutputPort("applied_torque")}   # the motors' torque after saturation
    log = [y, "motor_torque_command", "state", loop.references[0]] + [n for n, on in extra.items() if on]
    res = simulate(loop, ctx, t_final, inputs=inputs, log=log, log_period=dt, max_step=p.max_step, accuracy=1e-6)
    if slack:
        meta["tendon_force"] = res["tendon_force"]
    if extra["applied_torque"]:
        meta["applied_torque"] = res["applied_torque"]
    t = res.t - res.t[0]
    w = res["external_torque"][:, 0] if "external_torque" in res else np.zeros(len(t))
    run = TestRun(controller, test, t, res[loop.references[0]][:, 0], res[y][:, 0], res["motor_torque_command"], w,
                  res["state"], meta)
    m = Metrics(controller, test, joint="tendon" if y == "tendon_force" else "link")
    ratio = _command_metrics(m, run.command, run.meta.get("applied_torque", run.command),
                             torque_limit(loop, run.command.shape[1]), dt, run.meta.get("tendon_force"))
    if test == "disturbance":
        m.load_torque = p.disturbance_torque
    diagram = _set_test_metrics(m, test, p, run.t, run.reference, run.output, r0)
    if test == "sweep":
        run.meta.update(freq=diagram[0], gain=diagram[1])
        if lin_bw is not None:
            m.bandwidth_hz, m.bandwidth_source = lin_bw, "linearization"
    flag_run(m, p, ratio)
    return run, m


def _command_metrics(row: Metrics, command, applied, limit, dt: float, tendon_force=None) -> float | None:
    """Set ``row``'s peak command and input (``applied``: after saturation), saturation (:func:`_saturation`, whose
    peak ratio it returns) and slack (``tendon_force``, None: not tension-only) from its motors' logs."""
    u = np.abs(command)
    row.peak_command = float(np.max(u))
    row.peak_input = float(np.max(np.abs(applied)))
    if tendon_force is not None:
        row.slack_fraction = float(np.mean(np.any(tendon_force <= 0.0, axis=1)))
    return _saturation(row, u, limit, dt)


def _saturation(row: Metrics, u, limit, dt: float) -> float | None:
    """Set ``row.saturated_fraction`` and ``saturated_time`` from the commands' magnitudes ``u`` (samples x motors,
    logged every ``dt``) against the per-motor ``limit`` (None: no limit); return the command's peak as a multiple
    of its motor's limit (None without a limit)."""
    if limit is None:
        return None
    limit = np.asarray(limit, dtype=float)
    over = np.any(u > limit[None, :] * (1 + 1e-9), axis=1)
    row.saturated_fraction = float(np.mean(over))
    row.saturated_time = float(np.count_nonzero(over) * dt)
    return float(np.max(u / limit[None, :]))


def run_joint_test(loop: ClosedLoop, test: str, *, controller: str = "controller",
                   params: CompareTestParams | None = None, settled=None) -> tuple[TestRun | None, list[Metrics]]:
    """One standard test on a finger/hand loop: every DoF at once, one :class:`Metrics` row per DoF.

    A simulation stopped by a physical failure (:data:`~awiwi_drake.analysis.PHYSICAL_FAILURES`) gives its
    joints :func:`stopped_row` rows; the run is None when every simulation of the test stopped.

    ``step``/``sine``/``sweep``: the same reference change on every DoF (relative to the operating
    point) in one simulation: the rows include the interaction of a finger's joints moving together.
    ``disturbance``: ``disturbance_torque`` on the k-th joint of every finger at once (one
    simulation per k; the other joints of the finger are held by the controller only), stiffness
    ``dtau / dq`` of the loaded joint.  Peak input and saturation are per finger (its motors).
    """
    if test not in TESTS:
        raise ValueError(f"unknown test {test!r}; known: {', '.join(TESTS)}")
    ch = joint_channels(loop)
    if ch is None:
        raise ValueError("run_joint_test: the loop does not track the joint angles of a finger/hand")
    p = params or compare_test_params(loop.rig)
    dt = _sample_dt(loop, p)
    k = len(ch.names)
    r0 = p.initial_reference
    ref_port = loop.references[0]
    base = settled if settled is not None else settle(loop, r0, t_settle=p.settle_time, max_step=p.max_step)
    groups = ch.disturbance_groups() if test == "disturbance" else [list(range(k))]
    n_ext = loop.diagram.GetInputPort("external_torque").size() if "external_torque" in loop.disturbances else 0
    if test == "disturbance" and not n_ext:
        raise ValueError(f"test 'disturbance' needs a rig input 'external_torque'; rig "
                         f"{getattr(loop.rig, 'name', '?')!r} has none")
    applied = applied_port(loop)
    design = _design(loop)
    band, hold = (None, None) if design is None else (design.dead_band, design.friction_hold)
    impedance = design_stiffness(loop)                     # the designed static stiffness per DoF
    rows = [Metrics(controller, test, joint=nm) for nm in ch.names]
    loads, notes = np.full(k, p.disturbance_torque), [""] * k
    if (test == "disturbance" and p.load_bound_factor > 0 and impedance is not None
            and loop.diagram.HasOutputPort(OBSERVER_BOUND)):           # sized above the observer's bound (size_loads)
        loads, notes = size_loads(p, impedance, loop.diagram.GetOutputPort(OBSERVER_BOUND).Eval(base))
    if band is not None:
        for row, b in zip(rows, band):
            row.dead_band = float(b)
    meta: dict[str, Any] = {"joints": list(ch.names), "fingers": list(ch.fingers)}
    # ESTIMATION_ERROR: no joint sensors, the estimator's error
    log = ["joint_angle", ref_port, "motor_torque_command", "state", applied]
    log += [n for n in ("tendon_force", DISTRIBUTION_STATUS, ESTIMATION_ERROR) if loop.diagram.HasOutputPort(n)]
    log += [OBSERVER_COMPENSATION, OBSERVER_BOUND] if loop.diagram.HasOutputPort(OBSERVER_BOUND) else []
    Sp = np.linalg.pinv(ch.S)
    runs_t = runs_r = runs_u = runs_a = runs_w = runs_x = None
    failed: list[int] = []
    for group in groups:
        ctx = base.Clone()
        ctx.SetTime(0.0)
        sched, t_final = _schedule(test, p, r0)
        if test == "sweep":
            meta.update(f_low=p.sweep_start, f_high=p.sweep_stop)
        inputs = {ref_port: joint_inputs(ch, [sched] * k)}
        if n_ext:
            ext = [Constant(0.0)] * n_ext
            if test == "disturbance":
                for j in group:
                    ext[int(np.flatnonzero(ch.S[:, j])[0])] = Step(p.step_delay, float(loads[j]))
            inputs["external_torque"] = PerEntry(ext)
        try:
            res = simulate(loop, ctx, ctx.get_time() + t_final, inputs=inputs, log=log, log_period=dt,
                           max_step=p.max_step, accuracy=1e-6)
        except PHYSICAL_FAILURES as exc:   # this group's rows only; the other groups' simulations go on
            for j in group:
                rows[j] = stopped_row(controller, test, ch.names[j], exc)
            failed += group
            continue
        t = res.t - res.t[0]
        y = res["joint_angle"] @ Sp.T - ch.q0
        r = res[ref_port] @ Sp.T - ch.q0
        if runs_t is None:
            runs_t, runs_r, runs_u, runs_a, runs_x = t, r, res["motor_torque_command"], res[applied], res["state"]
            runs_y = y.copy()
            runs_w = np.zeros((len(t), k))
        for j in group:
            runs_y[:, j] = y[:, j]
            row = rows[j]
            sl = ch.tendons[j]
            limit = torque_limit(loop, res["motor_torque_command"].shape[1])
            ratio = _command_metrics(row, res["motor_torque_command"][:, sl], res[applied][:, sl],
                                     None if limit is None else limit[sl], dt,
                                     res["tendon_force"][:, sl] if "tendon_force" in res else None)
            if ESTIMATION_ERROR in res:
                joint = int(np.flatnonzero(ch.S[:, j])[0])          # the plant joint the DoF is named after
                row.estimation_error = float(np.max(np.abs(res[ESTIMATION_ERROR][:, joint])))
            if test == "disturbance":
                row.load_torque = float(loads[j])
                runs_w[:, j] = np.where(t >= p.step_delay, row.load_torque, 0.0)
            diagram = _set_test_metrics(row, test, p, t, r[:, j], y[:, j], r0)
            if diagram is not None:
                meta.setdefault("freq", diagram[0])
                meta.setdefault("gain_by_joint", {})[ch.names[j]] = diagram[1]
            flag_run(row, p, ratio)
            tail = t >= 0.9 * t[-1]                # the run's last 10 %, as the load test's end values
            if OBSERVER_BOUND in res and test == "disturbance":   # at its bound under a sized load: as designed
                mark_load(row, p, float(np.mean(res[OBSERVER_BOUND][tail, j])),
                          None if impedance is None else float(impedance[j]), notes[j])
            elif OBSERVER_BOUND in res and observer_at_bound(res[OBSERVER_COMPENSATION][tail, j],
                                                             res[OBSERVER_BOUND][tail, j]):
                row.flags = "; ".join(f for f in (row.flags, "observer at friction bound") if f)
                row.status = "flagged" if row.status == "ok" else row.status
            if DISTRIBUTION_STATUS in res:       # the chain's force distribution, one status per finger
                finger = list(dict.fromkeys(ch.fingers)).index(ch.fingers[j])
                bad = float(np.mean(res[DISTRIBUTION_STATUS][:, finger] != 0.0))
                if bad > 0.0:
                    row.flags = "; ".join(f for f in (row.flags, f"force distribution out of bounds "
                                                                 f"{100 * bad:.0f} %") if f)
                    row.status = "flagged" if row.status == "ok" else row.status
        if hold is not None and test == "step":      # the end errors of every DoF (the whole finger rests together)
            tail = t >= 0.9 * t[-1]
            mark_dead_band(rows, np.mean(y[tail] - r[tail], axis=0), hold)
    if runs_t is None:   # every simulation of the test stopped: rows only, nothing to plot
        return None, rows
    runs_y[:, failed] = np.nan   # the stopped groups' joints have no trace
    meta["applied_torque"] = runs_a
    return TestRun(controller, test, runs_t, runs_r, runs_y, runs_u, runs_w, runs_x, meta), rows


def flag_run(m: Metrics, params: CompareTestParams, command_ratio: float | None = None) -> Metrics:
    """Set ``m.flags`` / ``m.status`` from the metrics: a run that finished is not necessarily a success.

    Flags: ``saturated`` (saturated fraction > ``params.max_saturated_fraction``), ``command peak N x the torque
    limit for T ms`` (``command_ratio``, the command's peak over its motor's limit, > ``params.max_command_ratio``,
    however short: ``peak_input`` stays the applied, saturated torque), ``slack`` (slack
    fraction > ``params.max_slack_fraction``), ``not settled`` (step test never enters the settling band;
    disturbance test still drifting at its end: ``drift`` > settling band x deflection),
    ``negative stiffness`` (disturbance test: the link moves *with* the load).
    """
    flags = []
    if m.saturated_fraction > params.max_saturated_fraction:
        flags.append(f"saturated {100 * m.saturated_fraction:.0f} %")
    if command_ratio is not None and command_ratio > params.max_command_ratio:
        flags.append(f"command peak {command_ratio:.3g} x the torque limit for {1e3 * m.saturated_time:.3g} ms")
    if m.slack_fraction > params.max_slack_fraction:
        flags.append(f"slack {100 * m.slack_fraction:.0f} %")
    if m.test == "step" and not math.isfinite(m.settling_time):
        flags.append("not settled")
    load = m.load_torque if math.isfinite(m.load_torque) else params.disturbance_torque
    if m.test == "disturbance" and m.drift > params.settling_band * abs(load / m.stiffness):
        flags.append("not settled")
    if m.test == "disturbance" and m.stiffness < 0:
        flags.append("negative stiffness")
    m.flags = "; ".join(flags)
    if flags and m.status == "ok":
        m.status = "flagged"
    return m


def stopped_row(controller: str, test: str, joint: str, exc: Exception, *, settling: bool = False) -> Metrics:
    """The row of a case whose simulation stopped on a physical failure: metrics NaN, ``status`` the cause
    (``diverged``, ``infeasible_force``, a monitor's event kind), ``failed_at`` the test time [s] (while
    ``settling`` at the start reference: NaN, and the flags say so), ``flags`` the error's message."""
    return Metrics(controller, test, joint=joint, status=exc.status, failed_at=math.nan if settling else exc.t,
                   flags=("while settling at the initial reference: " if settling else "") + str(exc))


def default_tests(loop: ClosedLoop) -> list[str]:
    """The standard tests that apply to ``loop``: ``disturbance`` only with ``external_torque``, ``sweep`` not on
    fingers/hand (their tests: step, sine, external-torque step)."""
    return [t for t in TESTS if (t != "disturbance" or "external_torque" in loop.disturbances)
            and (t != "sweep" or joint_channels(loop) is None)]


def run_standard_tests(loop: ClosedLoop, *, controller: str = "controller", tests: Sequence[str] | None = None,
                       params: CompareTestParams | None = None,
                       progress: Callable[[str], Any] | None = None) -> tuple[list[TestRun], list[Metrics]]:
    """All applicable standard tests on one closed loop (``disturbance`` only with ``external_torque``).

    Each case is independent: a simulation stopped by a physical failure
    (:data:`~awiwi_drake.analysis.PHYSICAL_FAILURES`: divergence, an infeasible tendon force, a
    raising monitor) becomes :func:`stopped_row` rows (status = the cause, ``failed_at``, NaN
    metrics) and the other tests go on; programming errors propagate.

    ``progress(label)`` is called after each test (e.g. to advance a progress bar).
    """
    p = params or compare_test_params(loop.rig)
    channels = joint_channels(loop)
    tests = default_tests(loop) if tests is None else tests
    names = channels.names if channels is not None else ["tendon" if loop.tracked_outputs[0] == "tendon_force"
                                                          else "link"]
    runs, rows = [], []
    try:
        settled = settle(loop, p.initial_reference, t_settle=p.settle_time, max_step=p.max_step)
    except PHYSICAL_FAILURES as exc:   # no test can start: every row of this loop says why
        for test in tests:
            rows += [stopped_row(controller, test, nm, exc, settling=True) for nm in names]
            if progress is not None:
                progress(f"{controller}/{test}")
        return runs, rows
    for test in tests:
        try:
            if channels is None:
                run, m = run_test(loop, test, controller=controller, params=p, settled=settled)
                ms = [m]
            else:
                run, ms = run_joint_test(loop, test, controller=controller, params=p, settled=settled)
        except PHYSICAL_FAILURES as exc:   # this case's rows only; the other tests and controllers go on
            run, ms = None, [stopped_row(controller, test, nm, exc) for nm in names]
        if run is not None:
            runs.append(run)
        rows += ms
        if progress is not None:
            progress(f"{controller}/{test}")
    return runs, rows


def compare(loops: Mapping[str, ClosedLoop], *, tests: Sequence[str] | None = None,
            params: CompareTestParams | None = None, progress: Callable[[str], Any] | None = None) -> Comparison:
    """Run the standard tests on every closed loop ``{name: loop}`` (``progress(label)`` after each test)."""
    if not loops:
        raise ValueError("compare: give at least one closed loop")
    runs, rows = [], []
    rig = ""
    for name, loop in loops.items():
        r, m = run_standard_tests(loop, controller=name, tests=tests, params=params, progress=progress)
        runs += r
        rows += m
        rig = getattr(loop.rig, "name", rig)
    return Comparison(runs, MetricsTable(rows), rig)


def factory_options(names: Sequence[str], rig: Any, options: Mapping[str, Any] | None) -> dict:
    """``options`` for the factories of the controllers ``names`` (``chain_params``, ``stiffness_correction``:
    :class:`~awiwi_drake.parameters.cli.CompareControllerParams`); ValueError naming a controller that takes one
    not (its factory's ``takes``)."""
    options = dict(options or {})
    for n in names:
        bad = sorted(set(options) - getattr(get_entry(n, rig).factory, "takes", frozenset()))
        if bad:
            raise ValueError(f"controller {n!r} on {getattr(rig, 'name', rig)!r} takes no {', '.join(bad)} (the finger/hand chain "
                             f"controllers take chain_params and stiffness_correction, the backstepping ones "
                             f"chain_params)")
    return options


def build_loops(make_rig: Callable[[], Any], names: Sequence[str], controller_options: Mapping[str, Any] | None = None,
                **loop_options: Any) -> dict[str, ClosedLoop]:
    """The compared closed loops ``{name: loop}``, each registered controller built ONCE on a fresh rig from
    ``make_rig()`` (a hand design costs ~0.5-1.6 s): what :func:`design_step_duration` / :func:`short_test_params`
    read the designs' time constants from and :func:`compare` runs.  ``loop_options`` (``rate_hz``, ``delay``,
    ``saturation``, ``sensors``) override the registry's defaults for :func:`awiwi_drake.control.base.closed_loop`;
    ``controller_options`` go to every controller's factory (:func:`factory_options`).  Names are validated (unknown /
    not fitting the rig / not taking an option: ValueError) before anything is built."""
    names = list(names)
    if not names:
        raise ValueError("compare: give at least one controller name")
    probe = make_rig()
    entries = [get_entry(n, probe) for n in names]
    extra = factory_options(names, probe, controller_options)
    loops = {}
    for n, entry in zip(names, entries):
        rig = make_rig()
        loops[n] = closed_loop(rig, make_controller(n, rig, **extra), **{**entry.loop_options, **loop_options})
    return loops


def _loops(loops: Any) -> Mapping[str, ClosedLoop]:
    if not isinstance(loops, Mapping) or not all(isinstance(v, ClosedLoop) for v in loops.values()) or not loops:
        raise ValueError(f"give the compared loops {{name: ClosedLoop}} (build_loops), not {type(loops).__name__}")
    return loops


def design_step_duration(make_rig: Callable[[], Any], loops: Mapping[str, ClosedLoop],
                         params: CompareTestParams | None = None) -> float | None:
    """The step window [s] the compared loops' own designs need: ``step_delay + step_time_constants x`` the slowest
    tracking time constant of the loops ``{name: loop}`` (:func:`build_loops`,
    :class:`~awiwi_drake.parameters.cli.CompareShortMode`); at least the chosen ``params.step_duration`` when some
    loop has none (so adding it never shortens the others' window); None when no loop has one.  ``compare --short``
    steps for it, the full tests for at least it, so that a loop that performs as designed settles.

    Fingers and the hand: the designs' own :func:`design_time_constant` (their plant's hysteresis states would put zero
    eigenvalues in a linearisation); single-joint rigs: :func:`dominant_time_constant` of the continuous twin of each
    loop (the registered controller on a fresh ``make_rig()`` without rate and delay, for Drake ``Linearize``)."""
    from awiwi_drake.parameters.cli import CompareShortMode

    loops = _loops(loops)
    probe = next(iter(loops.values())).rig
    p = params or compare_test_params(probe)
    taus = []
    for n, loop in loops.items():
        if rig_kind(probe) in ("finger", "hand"):
            taus.append(design_time_constant(loop))
            continue
        rig = make_rig()
        twin = closed_loop(rig, make_controller(n, rig), **{**get_entry(n, rig).loop_options, "rate_hz": None,
                                                            "delay": None})
        taus.append(dominant_time_constant(twin, p))
    known = [t for t in taus if t is not None]
    if not known:
        return None
    window = p.step_delay + CompareShortMode().step_time_constants * max(known)
    # a loop without a known time constant keeps at least the chosen window, and does not shorten the others'
    return window if len(known) == len(taus) else max(window, p.step_duration)


def short_test_params(make_rig: Callable[[], Any], loops: Mapping[str, ClosedLoop],
                      params: CompareTestParams | None = None) -> CompareTestParams:
    """The standard tests shortened (``compare --short``, ``AWIWI_SHORT=1``) for the loops ``{name: loop}``
    (:func:`build_loops`) so that they still settle (:class:`~awiwi_drake.parameters.cli.CompareShortMode`): the
    step window is :func:`design_step_duration`, at least ``min_step_duration`` and not capped at the full one (the
    full window is kept when a loop has no known time constant); shorter sweep, settling and sine (fingers/hand: two
    periods at >= 4 Hz)."""
    from awiwi_drake.parameters.cli import CompareShortMode

    probe = next(iter(_loops(loops).values())).rig
    p = params or compare_test_params(probe)
    sm = CompareShortMode()
    window = design_step_duration(make_rig, loops, p)
    step = p.step_duration if window is None else max(sm.min_step_duration, window)
    short = p.replace(step_duration=step, sweep_duration=min(p.sweep_duration, sm.sweep_duration),
                      settle_time=min(p.settle_time, sm.settle_time), sine_periods=sm.sine_periods)
    return short.replace(sine_frequency=max(p.sine_frequency, 4.0)) if rig_kind(probe) in ("finger", "hand") else short


def compare_controllers(make_rig: Callable[[], Any], names: Sequence[str], *, tests: Sequence[str] | None = None,
                        params: CompareTestParams | None = None, progress: Callable[[str], Any] | None = None,
                        controller_options: Mapping[str, Any] | None = None, **loop_options: Any) -> Comparison:
    """:func:`build_loops` then :func:`compare` (the standard tests of ``make_rig()``'s kind unless ``params``).
    A derived window (:func:`short_test_params`, :func:`design_step_duration`) reads the same built loops:
    ``loops = build_loops(...)``, ``compare(loops, params=short_test_params(make_rig, loops))``."""
    loops = build_loops(make_rig, names, controller_options, **loop_options)
    rig = next(iter(loops.values())).rig
    return compare(loops, tests=tests, params=params or compare_test_params(rig), progress=progress)


# plotting (data in, (fig, ax) out)
