"""The discrepancy workflow on a finger: localise to tendons, name effect and place (issue 12 item 5).

A finger dataset holds what the hand measures: the commanded motor torques, the motor angles and the tendon
forces (joint angles optional).  With the force measured at every spring mechanism, the finger splits into
two checks per tendon, each a law of the package's own finger (:func:`~awiwi_drake.hand.diagrams.finger_diagram`
of the dataset's :class:`~awiwi_drake.parameters.hand.FingerRigParams`):

* **motor side** (tendon ``i``): the motor law :func:`~awiwi_drake.components.motor.motor_acceleration`
  ``B w' = u - d w - r f`` with the measured force as the load; its torque residual holds whatever acts on that
  motor or between motor and sensor (motor friction, ripple, inertia and damping errors) and nothing from the
  rest of the finger;
* **spring side**: the spring laws ``f_i = F_i(x_i)`` with the routing ``x = x0 + r theta + h(q) - h(0)``;
  the joint angles are estimated from all tendons at once (weighted least squares, ``m > n``), so the
  ``m - n`` redundant tendon directions carry what one spring mechanism does differently (hysteresis, a
  force-sensor offset, a scale error);
* **joint side**: the links' equation ``M(q) q'' + C(q, q') q' + d q' + G [q; q'] = -P^T (f + g)`` with the
  measured forces and the joint angles estimated from the tendons: its residual holds the guide friction ``g`` of
  the tendon paths, which acts between the force sensor and the joints ("the tendon force measurements are
  performed into the forearm", ch. 4) and so shows in neither the motor nor the spring law. The constant part of
  a path's guide friction is the same generalised force as its antagonist's (opposite rows of ``P``): such a pair
  is one class "not separable" with these data.

Both are equation errors, made exact by **consistent filtering**: one Gaussian kernel ``H`` is applied to
both sides (``H''`` to the angle for the acceleration, ``H'`` for the velocity, ``H`` to the force and the
exact integral of ``H`` over each hold interval to the zero-order-held command), so the filtered law holds
for the filtered signals without a derivative of noise.  The residual is decimated to about one sample per
kernel width (so samples are nearly independent) and normalised by its noise level propagated from the
sensor noise floors (:func:`~awiwi_drake.discrepancy.replay.noise_floor`).

Each candidate (catalog effect x place, shape on the catalog's grid) is a regression of one tendon's
residual on the effect's law (:mod:`.laws`, the catalog forms) fitted on training blocks and scored on
held-out blocks; acceptance is the rigs' (:mod:`.decide`): held-out gain above ``min_z`` null standard
deviations, BIC better than without it, no amplitude at a bound, material (effect RMS above
``finger_material`` times the noise-equivalent torque/force); candidates that explain the same residual as
well are one class "not separable" with the experiment that would separate them.  Greedy: the accepted
effect is subtracted and the search repeats until the held-out residual is at the noise floor or nothing
passes; above ``unexplained_ratio`` times the floor the verdict says an unexplained discrepancy remains,
naming the tendons where it is.

Why not a multiple-shooting replay as on the rigs: one pass of the finger diagram costs about as much as
generating the dataset and a screen needs tens to hundreds; with motor angles and tendon forces measured, the
motor and spring laws localise the effect without integrating the links. The one replay is a named hysteresis
loop's write-back (:meth:`FingerResiduals.replay`, :func:`_hysteresis_law_fit`): a Dahl state on the noisy
measured elongation is relaxed by the noise, on the replayed finger's it is not.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from types import SimpleNamespace

import numpy as np
from scipy.special import ndtr

from awiwi_drake.analysis import SimulationDivergedError
from awiwi_drake.components.friction import dahl_path
from awiwi_drake.components.motor import motor_acceleration, motor_friction_torque, motor_ripple_torque
from awiwi_drake.hand.diagrams import finger_diagram
from awiwi_drake.parameters.components import HysteresisParams
from awiwi_drake.parameters.control import CONTROL_RATE_HZ
from awiwi_drake.parameters.discrepancy import CatalogBounds, DiscrepancySettings

from . import laws
from .augment import AugmentedParameters, augmented_finger_parameters
from .data import Dataset, finger_parameters_from_json, finger_parameters_to_json, is_finger_rig
from .decide import separating_experiment
from .finger_truth import with_loop
from .replay import noise_floor, play_operator
from .screen import gain_z

__all__ = ["FingerResiduals", "FingerStep", "FingerDiagnosis", "diagnose_finger", "JOINT_LABELS",
           "tendon_place"]

JOINT_LABELS = {"0": "abduction", "1": "MCP", "2": "PIP", "3": "DIP", "h": "HMC"}
"""Plant joint ``q<digit><j>`` -> anatomical name (section 5.1: abduction, MCP, PIP, DIP; the fifth's HMC)."""

MOTOR_SIDE = ("motor_friction", "motor_ripple", "nominal_motor")
SPRING_SIDE = ("spring_hysteresis", "nominal_spring", "force_sensor")
JOINT_SIDE = ("guide_friction",)
NUISANCE = ("nominal_motor", "nominal_spring", "force_sensor")


def tendon_place(rig, i: int) -> str:
    """``"index_h5 (PIP)"``: the tendon's name and the joints it moves (nonzero routing entries)."""
    P = np.asarray(rig.coupling.P(np.zeros(rig.num_joints)) if not rig.coupling.is_constant
                   else rig.coupling.P(), float)
    joints = [JOINT_LABELS.get(rig.joint_names[j][-1], rig.joint_names[j]) for j in range(P.shape[1])
              if abs(P[i, j]) > 1e-12]
    return f"{rig.tendon_names[i]} ({', '.join(joints)})" if joints else rig.tendon_names[i]


# ---------------------------------------------------------------------------- consistent filtering
def _kernel(sigma: float, dt: float):
    """Gaussian kernel and its first two derivatives sampled on ``+-6 sigma`` (weights times dt): cut at 4 sigma,
    the second derivative's weights would not sum to 0 (a constant angle offset would show as a torque)."""
    half = int(math.ceil(6 * sigma / dt))
    s = np.arange(-half, half + 1) * dt
    g = np.exp(-0.5 * (s / sigma) ** 2) / (sigma * math.sqrt(2 * math.pi))
    g0, g1, g2 = g * dt, -s / sigma ** 2 * g * dt, (s ** 2 / sigma ** 4 - 1 / sigma ** 2) * g * dt
    g0 = g0 / g0.sum()
    g2 = g2 - g2.sum() * g0          # the rest of the cut (6e-8 of 1/sigma^2): a constant has no acceleration
    return s, g0, g1, g2


def _filter(y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``sum_j w(t_i - t_j) y_j`` (same length; the kernel's half-width at both ends is invalid and trimmed
    by the caller)."""
    return np.convolve(y, w, mode="same") if y.ndim == 1 else np.stack([_filter(c, w) for c in y])


def _filter_held(u: np.ndarray, sigma: float, dt: float, half: int) -> np.ndarray:
    """``integral H(t_i - s) u(s) ds`` for a command held on ``[t_k, t_k + dt)``: exact per interval."""
    k = np.arange(-half, half + 1) * dt     # t_i - t_j for the kernel's span
    w = ndtr(k / sigma) - ndtr((k - dt) / sigma)   # integral of H over [t_j, t_j + dt) seen from t_i
    return _filter(u, w)


def _windows(t: np.ndarray, mask: np.ndarray) -> list:
    """``[(t_start, t_end), ...]`` [s] of the runs of ``mask`` (consecutive decimated samples)."""
    k = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return [(float(t[a]), float(t[b - 1])) for a, b in zip(k[::2], k[1::2])]


# ---------------------------------------------------------------------------- residuals
class FingerResiduals:
    """Filtered motor- and spring-side residuals of one finger dataset (see the module docstring).

    Attributes (``K`` decimated samples, ``m`` tendons)
    ---------------------------------------------------
    theta, omega, alpha, force, torque : (m, K) filtered angle, velocity, acceleration, force, command
    tau : (m, K) motor-side torque residual [N m]; ``sigma_tau`` (m,) its noise level
    eps : (m, K) spring-side residual, elongation [m] weighted to unit noise and projected on the
        redundant tendon directions; ``proj`` (K, m, m) that projection (whitened)
    elong : (m, K) elongations of the estimated joint angles [m]; ``stiff`` (m, K) [N/m]
    train, test : (K,) bool, blocked split
    """

    def __init__(self, ds: Dataset, settings: DiscrepancySettings):
        if not is_finger_rig(ds.rig):
            raise ValueError(f"{ds.name}: rig {ds.rig!r} is not a finger")
        self.ds, self.settings = ds, settings
        self.params = fp = finger_parameters_from_json(ds.parameters, ds.name)
        self.finger = ds.parameters["finger"]
        rig = finger_diagram(finger=self.finger, params=fp)
        if fp.spring.hysteresis.enabled:
            raise ValueError(f"{ds.name}: parameters.finger_rig: spring.hysteresis.enabled must be false (the nominal "
                             f"finger may hold motor friction and ripple per tendon (tendon_motors), a hysteresis "
                             f"loop on single tendons (tendon_springs) and guide friction (guide_friction, "
                             f"tendon_guides))")
        self.rig = rig
        m, n, dt = rig.num_tendons, rig.num_joints, ds.dt
        self.m, self.n, self.dt = m, n, dt
        mp = rig.drive.model.motor          # the motor laws the finger diagram integrates (tendon_motors included)
        self.motors = motors = list(mp) if isinstance(mp, tuple) else [mp] * m
        r = fp.motor.pulley_radius
        B, d = np.array([p.inertia for p in motors]), np.array([p.damping for p in motors])
        self.r, self.B = r, B
        TH = np.stack([ds.outputs[f"motor_angle_{i + 1}"] for i in range(m)])
        F = np.stack([ds.outputs[f"tendon_force_{i + 1}"] for i in range(m)])
        U = np.stack([ds.inputs[f"motor_torque_{i + 1}"] for i in range(m)])
        if fp.motor.saturation and np.any(np.abs(U) > fp.motor.torque_limit):
            i, k = np.unravel_index(int(np.argmax(np.abs(U))), U.shape)
            raise ValueError(f"{ds.name}: column 'motor_torque_{i + 1}' reaches {U[i, k]:.3g} N m at t = "
                             f"{ds.time[k]:.4g} s, beyond motor.torque_limit = {fp.motor.torque_limit} N m: the "
                             f"applied torque is not the logged one")
        self.sig_theta = np.array([noise_floor(v) for v in TH])
        self.sig_force = np.array([noise_floor(v) for v in F])
        sigma = settings.finger_filter
        s, g0, g1, g2 = _kernel(sigma, dt)
        half = (len(s) - 1) // 2
        self._g0 = g0
        th, om, al = _filter(TH, g0), _filter(TH, g1), _filter(TH, g2)
        f = _filter(F, g0)
        u = _filter_held(U, sigma, dt, half)
        # motor law of the package: its linear part (u, d w, r f) on the filtered signals (exact), its friction
        # and ripple evaluated on the filtered angle and velocity and filtered once more (as the candidates)
        lin = [p.replace(friction=False, ripple=False) for p in motors]
        acc = np.stack([motor_acceleration(th[i], om[i], u[i], r * f[i], lin[i]) for i in range(m)])
        tau = B[:, None] * (al - acc)
        for i, p in enumerate(motors):
            if p.ripple:
                tau[i] -= _filter(motor_ripple_torque(th[i], p), g0)
        # the inertia-error signature: the acceleration filtered 4x wider, nearly free of the angle noise
        # that the residual's own acceleration carries (no errors-in-variables fit of noise on itself)
        s4, _, _, g2w = _kernel(4 * sigma, dt)
        acc_wide = _filter(TH, g2w)
        # decimation: one sample per ``finger_decimation`` kernel deviations; laws evaluated on the filtered
        # full-rate signals are filtered once more (:meth:`consistent`), so both filters' margins are cut
        step = max(1, int(round(settings.finger_decimation * sigma / dt)))
        trim = 2 * ((len(s4) - 1) // 2)
        self._sl = slice(trim, len(ds.time) - trim, step)
        sl = self._sl
        self.full = {"theta": th, "omega": om, "force": f}
        self._force_raw = F
        self.time = ds.time[sl]
        self.theta, self.omega, self.alpha, self.force, self.torque = th[:, sl], om[:, sl], al[:, sl], f[:, sl], u[:, sl]
        self.tau, self.acc_wide = tau[:, sl], acc_wide[:, sl]
        # the motor's known acceleration (its linear law with the measured force and the held command) integrated
        # twice: the motion the motor law explains, exact at the sample rate (motor_velocity)
        known = np.stack([motor_acceleration(TH[i], om[i], U[i], r * F[i], lin[i]) for i in range(m)])
        self._omega_known = np.concatenate([np.zeros((m, 1)), np.cumsum(known[:, :-1], axis=1) * dt], axis=1)
        self._theta_known = np.concatenate([np.zeros((m, 1)), np.cumsum(
            self._omega_known[:, :-1] + self._omega_known[:, 1:], axis=1) * dt / 2], axis=1)
        self._theta_raw, self._velocities = TH, {}
        self.motor_filters = {}       # tendon -> velocity filter [s] of the nominal's own friction (as a candidate's)
        for i, p in enumerate(motors):
            if p.friction:       # the width the data fit best (motor_velocity), as a candidate's shape is chosen
                fric = {w: self.consistent(motor_friction_torque(self.motor_velocity(i, w), p.replace(damping=0.0)))
                        for w in settings.finger_motion_filters}
                w = min(fric, key=lambda w: float(np.sum((self.tau[i] - fric[w]) ** 2)))
                self.motor_filters[i] = w
                self.tau[i] -= fric[w]
        # noise of the torque residual: B H'' theta-noise and r H f-noise (and d H' theta-noise)
        self.sigma_tau = np.sqrt((B * np.linalg.norm(g2)) ** 2 * self.sig_theta ** 2
                                 + (d * np.linalg.norm(g1)) ** 2 * self.sig_theta ** 2
                                 + (r * np.linalg.norm(g0)) ** 2 * self.sig_force ** 2)
        self._spring_side(np.linalg.norm(g0))
        self._joint_side(TH, g0, g1, g2)
        K = self.tau.shape[1]
        nb = max(int(round(settings.finger_block / (step * dt))), 1)
        self.folds = (np.arange(K) // nb) % 3      # blocked 3-fold cross-validation
        self.test = self.folds == 2                 # the fold the reported ratios are held out on
        self.train = ~self.test
        self.step = step
        self._signature_cache: dict = {}     # candidate columns per (effect, tendon): data only (_signatures)

    def motor_velocity(self, i: int, width: float) -> np.ndarray:
        """Motor ``i``'s velocity [rad/s] at the full rate, what a nonlinear velocity law (friction (3.8)) is
        evaluated on before the consistent filter: the motion the motor's known law explains (its linear law with
        the measured force and the held command, integrated twice: ``omega_k``, ``theta_k``) plus the derivative of
        the rest ``theta - theta_k`` smoothed by a Gaussian of ``width`` [s] (from ``finger_motion_filters``, chosen
        by the data). Only the unknown torques' motion is smoothed: (3.8) of a velocity smoothed as a whole is not
        the filtered friction (the finger's fast motion is gone within the filter's 20 ms)."""
        key = (i, width)
        if key not in self._velocities:
            self._velocities[key] = self._omega_known[i] + _filter(self._theta_raw[i] - self._theta_known[i],
                                                                   _kernel(width, self.dt)[2])
        return self._velocities[key]

    def consistent(self, signal: np.ndarray) -> np.ndarray:
        """A full-rate signal (a law evaluated on the filtered signals :attr:`full`, or on raw ones) filtered by
        the same kernel and decimated: how it shows in the filtered residuals."""
        return _filter(np.asarray(signal, float), self._g0)[..., self._sl]

    def _spring_side(self, g0: float) -> None:
        """Joint angles from all tendons (weighted least squares on the elongations the spring laws give for
        the measured forces); residual in the redundant directions, whitened."""
        rig, m, r = self.rig, self.m, self.r
        laws_t = rig.spring_laws
        P = np.asarray(rig.coupling.P(), float) if rig.coupling.is_constant else None
        # elongations the spring laws give for the measured forces, at full rate, then filtered: the routing
        # is linear in them, so the filtered relation y = P q holds exactly (consistent filtering; the thumb's
        # h(q) is not linear: there it holds to the curvature of h over the kernel's width)
        raw = np.maximum(self._force_raw, 1e-3)
        hyst = rig.drive.model.hysteresis      # a nominal loop on single tendons (tendon_springs): its force removed,
        if isinstance(hyst, tuple) and any(h.enabled for h in hyst):   # the loop of the finger replayed (replay)
            z = self.replay(self.params)["loop"]
            for i, h in enumerate(hyst):
                if h.enabled:
                    raw[i] = np.maximum(raw[i] - z[i], 1e-3)
        self._x_full = np.stack([np.asarray(laws_t[i].inverse_force(raw[i]), float) for i in range(m)])
        xm = self.consistent(self._x_full)
        stiff = np.stack([np.asarray(laws_t[i].stiffness(xm[i]), float) for i in range(m)])
        y = xm - rig.offsets[:, None] - r * self.theta            # = P q (+ noise + what the laws miss)
        # noise of y_i: the force noise through the spring, the angle noise through the pulley (filtered)
        var = (g0 * self.sig_force[:, None] / stiff) ** 2 + (g0 * r * self.sig_theta[:, None]) ** 2
        wsq = 1.0 / np.sqrt(var)                                    # (m, K)
        K = y.shape[1]
        yw = (wsq * y).T                                            # (K, m)
        self.not_converged = []      # time windows [s] where the thumb's Gauss-Newton did not converge
        if P is not None:
            A = wsq.T[:, :, None] * P[None]                         # (K, m, n) whitened routing
            self.q_hat = np.stack([np.linalg.lstsq(A[k], yw[k], rcond=None)[0] for k in range(0, K)], axis=1)
            hq = P @ self.q_hat
        else:       # the thumb: y = h(q) - h(0), weighted Gauss-Newton per sample, the routing linearised at q_hat
            c, n = rig.coupling, self.n
            h0 = np.asarray(c.h(np.zeros(n)), float)
            Q, A = np.zeros((K, n)), np.empty((K, m, n))
            iters, tol = self.settings.finger_gauss_newton_iterations, self.settings.finger_gauss_newton_tolerance
            stuck = np.zeros(K, dtype=bool)
            for k in range(K):
                q = Q[k - 1] if k else np.zeros(n)
                for _ in range(iters):
                    A[k] = wsq[:, k, None] * np.asarray(c.P(q), float)
                    dq = np.linalg.lstsq(A[k], yw[k] - wsq[:, k] * (np.asarray(c.h(q), float) - h0), rcond=None)[0]
                    q = q + dq
                    if np.max(np.abs(dq)) < tol:
                        break
                else:
                    stuck[k] = True
                Q[k] = q
                A[k] = wsq[:, k, None] * np.asarray(c.P(q), float)
            self.not_converged = _windows(self.time, stuck)
            self.q_hat = Q.T
            hq = np.stack([np.asarray(c.h(q), float) - h0 for q in Q], axis=1)
        Qm, _ = np.linalg.qr(A)                                     # (K, m, n)
        proj = np.eye(m)[None] - Qm @ np.transpose(Qm, (0, 2, 1))   # whitened residual projector
        # the whitened residual of the fit, in the redundant directions (= proj @ yw for a constant routing)
        self.eps = np.einsum("kij,kj->ik", proj, yw - (wsq * hq).T)
        self.proj, self.wsq, self.stiff = proj, wsq, stiff
        self.elong = rig.offsets[:, None] + r * self.theta + hq

    def loop_removed(self, i: int, z: np.ndarray) -> np.ndarray:
        """The spring-side residual's change (m, K) when tendon ``i``'s spring carries the loop force ``z`` [N]
        (full rate): removed from the measured force before the inverse spring law, as a nominal finger with that
        loop does (:meth:`_spring_side`), not linearised; the weights and the projection stay this residual's (they
        move by the loop's share of the stiffness only)."""
        law, F = self.rig.spring_laws[i], np.maximum(self._force_raw[i], 1e-3)
        shift = self.consistent(self._x_full[i] - np.asarray(law.inverse_force(np.maximum(F - z, 1e-3)), float))
        return (self.proj[:, :, i] * (self.wsq[i] * shift)[:, None]).T

    def replay(self, params) -> dict:
        """The package's finger (:func:`~awiwi_drake.hand.diagrams.finger_diagram` of ``params``, a
        :class:`~awiwi_drake.parameters.hand.FingerRigParams`) replayed on the recorded motor torques, with a weak
        spring ``finger_replay_stiffness`` (critically damped with the motor inertia) pulling each motor towards its
        measured angle smoothed by ``finger_motor_rest_filter``: open loop the motion that stretches no tendon
        drifts (motors and joints together, no motor damping), the tendons' own dynamics are 17x stiffer than the
        pull. Start: the smoothed angles and the joints from the smoothed elongations (least squares), loop forces
        0. Returns ``elongation`` (m, N) [m] and ``loop`` (m, N) [N] (the hysteresis forces, 0 without a loop),
        free of the sensor noise that relaxes a Dahl state run on the measured elongation. Cached per ``params``."""
        cache = self.__dict__.setdefault("_replays", {})
        if params in cache:
            return cache[params]
        from pydrake.systems.framework import DiagramBuilder
        from pydrake.systems.primitives import Adder, MatrixGain, TrajectorySource
        from pydrake.trajectories import PiecewisePolynomial
        from scipy.ndimage import gaussian_filter1d

        from awiwi_drake.analysis import simulate
        rig = finger_diagram(finger=self.finger, params=params)
        m, n, dt, t = self.m, self.n, self.dt, self.ds.time
        width = self.settings.finger_motor_rest_filter / dt
        th = gaussian_filter1d(self._theta_raw, width, axis=1, mode="nearest")
        om = gaussian_filter1d(self._theta_raw, width, axis=1, order=1, mode="nearest") / dt
        x = gaussian_filter1d(np.stack([np.asarray(law.inverse_force(np.maximum(f, 1e-3)), float)
                                        for law, f in zip(rig.spring_laws, self._force_raw)]), width, axis=1,
                              mode="nearest")
        c, y = rig.coupling, x[:, :2] - rig.offsets[:, None] - self.r * th[:, :2]
        h0 = np.asarray(c.h(np.zeros(n)), float)
        q = np.zeros((n, 2))
        for _ in range(self.settings.finger_gauss_newton_iterations):   # h(q) - h(0) = y at the first two samples
            for k in range(2):
                q[:, k] += np.linalg.lstsq(np.asarray(c.P(q[:, k]), float),
                                           y[:, k] - (np.asarray(c.h(q[:, k]), float) - h0), rcond=None)[0]
        K = self.settings.finger_replay_stiffness
        D = 2.0 * np.sqrt(K * self.B)
        b = DiagramBuilder()
        fd = b.AddNamedSystem("finger", rig.diagram)
        pull = b.AddNamedSystem("pull_to_measured", MatrixGain(-np.hstack([np.diag(np.full(m, K)), np.diag(D)])))
        add = b.AddNamedSystem("torque", Adder(2, m))
        b.Connect(fd.GetOutputPort("motor_state"), pull.get_input_port())
        b.Connect(pull.get_output_port(), add.get_input_port(1))
        b.Connect(add.get_output_port(), fd.GetInputPort("motor_torque"))
        U = np.stack([self.ds.inputs[f"motor_torque_{i + 1}"] for i in range(m)])     # held per sample, as logged
        w = b.AddNamedSystem("recorded_torque", TrajectorySource(PiecewisePolynomial.ZeroOrderHold(
            t, U + K * th + D[:, None] * om)))
        b.Connect(w.get_output_port(), add.get_input_port(0))
        b.ExportInput(fd.GetInputPort("external_torque"), "external_torque")
        b.ExportOutput(fd.GetOutputPort("state"), "state")
        diagram = b.Build()
        ctx = diagram.CreateDefaultContext()
        diagram.GetInputPort("external_torque").FixValue(ctx, np.zeros(n))
        x0 = np.zeros(diagram.num_continuous_states())
        x0[:n], x0[n:2 * n] = q[:, 0], (q[:, 1] - q[:, 0]) / dt
        x0[2 * n:2 * n + m], x0[2 * n + m:2 * n + 2 * m] = th[:, 0], om[:, 0]
        ctx.SetContinuousState(x0)
        res = simulate(diagram, ctx, t[-1], log=("state",), log_period=dt, mode="fixed_step",
                       step=min(dt, 1.0 / CONTROL_RATE_HZ))   # the control period (as the finger truth steps)
        S = np.asarray(res["state"], float).T
        if S.shape[1] != len(t):
            raise RuntimeError(f"{self.ds.name}: the finger replay logged {S.shape[1]} samples, expected {len(t)}")
        qs, ths = S[:n], S[2 * n:2 * n + m]
        elong = rig.offsets[:, None] + self.r * ths + np.stack([np.asarray(c.h(qk), float) - h0 for qk in qs.T], 1)
        loop = np.zeros((m, len(t)))
        for k, name in enumerate(rig.state_names):
            if name.startswith("hysteresis_force["):
                loop[rig.tendon_names.index(name[len("hysteresis_force["):-1])] = S[k]
        cache[params] = out = {"elongation": elong, "loop": loop}
        return out

    def _joint_side(self, TH: np.ndarray, g0, g1, g2) -> None:
        """The links' equation residual ``rho = M q'' + C q' + d q' + G [q; q'] + P^T (f + g_nominal)`` (n, K),
        whitened by the force noise through ``P^T``; the joint angles from the tendons at the full rate (the
        spring side's weighted least squares with each tendon's mean weight), filtered consistently. Only where
        the routing is constant (the thumb's is not: ``joint_checked`` False)."""
        rig, m, n = self.rig, self.m, self.n
        # only where the tendons fix every joint angle: the thumb's routing depends on q, and the ring's and fifth's
        # coupled PIP/DIP enter P as one combination (rank n - 1), so their estimated angles are not the plant's
        self.joint_checked = bool(rig.coupling.is_constant) and int(
            np.linalg.matrix_rank(np.asarray(rig.coupling.P(), float))) == n
        self.joint_reason = "" if self.joint_checked else (
            "its routing depends on the joint angles" if not rig.coupling.is_constant else
            "its coupled PIP/DIP enter the routing as one combination (the tendons do not fix every joint angle)")
        if not self.joint_checked:
            self.rho = np.zeros((n, self.tau.shape[1]))
            return
        from awiwi_drake.hand.dynamics import LinkModel
        P = np.asarray(rig.coupling.P(), float)
        w = np.mean(self.wsq, axis=1)                                      # (m,) mean whitening weight
        A = np.linalg.pinv(w[:, None] * P)
        # the motor angles as the motor law's motion plus the smoothed rest (motor_velocity), not the raw noisy ones
        w_rest = _kernel(self.settings.finger_motor_rest_filter, self.dt)[1]
        theta = self._theta_known + _filter(TH - self._theta_known, w_rest)
        y = self._x_full - rig.offsets[:, None] - self.r * theta            # (m, N) = P q + noise
        q_full = A @ (w[:, None] * y)                                      # (n, N)
        self.path = P @ q_full                                             # tendon travel at the guides [m]
        self._paths, self._guide_cols = {}, {}          # smoothed paths, guide columns (guide_columns)
        # the links' terms at the full rate, then filtered: M(q) q'' and C(q, q') q' are not linear in q, and the
        # finger's link modes (~500 Hz) move q within the kernel's width (on the filtered angles the rectified
        # fast-mode terms would be a residual). Central differences: the angle noise enters as H'' does
        v_full = np.gradient(q_full, self.dt, axis=1)
        a_full = np.gradient(v_full, self.dt, axis=1)
        links = LinkModel(rig.plant, rig.coupling_gain)
        plant, ctx = rig.plant, rig.plant.CreateDefaultContext()
        lhs = np.empty_like(q_full)
        for k in range(q_full.shape[1]):
            plant.SetPositions(ctx, q_full[:, k])
            plant.SetVelocities(ctx, v_full[:, k])
            lhs[:, k] = plant.CalcMassMatrix(ctx) @ a_full[:, k] + plant.CalcBiasTerm(ctx)
        lhs += links.damping[:, None] * v_full
        if links.coupling_gain is not None:
            lhs += links.coupling_gain @ np.vstack([q_full, v_full])
        rho = self.consistent(lhs) + P.T @ self.force
        cov = (np.linalg.norm(g0) ** 2) * (P.T * self.sig_force ** 2) @ P
        self._joint_whiten = np.linalg.cholesky(cov)
        self._P = P
        self.path_filters = {}        # tendon -> path filter [s] of the nominal's own guides (chosen as a candidate's)
        gm = rig.drive.model.guide_friction
        if gm is not None:                                  # the nominal finger's own guides, along the path
            C, E = gm.levels()
            for i in range(m):
                if C[i] or E[i]:        # the path filter the data fit best, as a candidate's shape is chosen
                    paths = {w: np.outer(P[i], self.consistent(self.guide_path(i, C[i], E[i], w, gm)))
                             for w in self.settings.finger_motion_filters}
                    w = min(paths, key=lambda w: float(np.sum(np.linalg.solve(self._joint_whiten, rho + paths[w]) ** 2)))
                    self.path_filters[i] = w
                    rho = rho + paths[w]
        self.rho = np.linalg.solve(self._joint_whiten, rho)

    def guide_path(self, i: int, constant: float, exponent: float, width: float, gm=None) -> np.ndarray:
        """Guide friction force [N] of tendon ``i``'s path at the full rate: the package's Dahl law
        (:func:`~awiwi_drake.components.friction.guide_friction_rate`, level
        :func:`~awiwi_drake.components.friction.guide_friction_level`) solved per sample
        (:func:`~awiwi_drake.components.friction.dahl_path`) along the estimated travel at the guides, smoothed by a
        Gaussian of ``width`` [s] first (from ``finger_motion_filters``, chosen by the data): every noise step of
        the raw travel would relax the Dahl state by ``|dx| / delta``, and a play operator would delay every true
        reversal. The path is linear in its level ``C + f (rise (1 + s) / 2 + loss (1 - s) / 2)``, so it is
        ``C U + rise D+ + loss D-`` (:meth:`guide_columns`)."""
        U, Dp, Dm = self.guide_columns(i, width, gm)
        return constant * U + np.expm1(exponent) * Dp - np.expm1(-exponent) * Dm

    def guide_columns(self, i: int, width: float, gm=None):
        """The Dahl paths of the level's three parts along tendon ``i``'s smoothed travel (:meth:`guide_path`):
        ``U`` (level 1 N), ``D+`` (level ``f (1 + s) / 2``), ``D-`` (level ``f (1 - s) / 2``), ``s`` the direction."""
        delta = gm.presliding_length if gm is not None else self.params.guide_presliding_length
        v_s = gm.smoothing_velocity if gm is not None else self.params.friction_smoothing_velocity
        key = (i, width, delta, v_s)
        if key not in self._guide_cols:
            path = self._smooth_path(i, width)
            s = np.tanh(np.clip(np.gradient(path) / (self.dt * v_s), -40.0, 40.0))
            f = np.maximum(self._force_raw[i], 0.0)
            self._guide_cols[key] = tuple(dahl_path(path, level, delta, 0.0, self.dt)    # |v| exactly
                                          for level in (np.ones_like(f), f * (1 + s) / 2, f * (1 - s) / 2))
        return self._guide_cols[key]

    def _smooth_path(self, i: int, width: float) -> np.ndarray:
        key = (i, width)
        if key not in self._paths:
            self._paths[key] = _filter(self.path[i], _kernel(width, self.dt)[1])
        return self._paths[key]

    # ------------------------------------------------------------------ energies
    def unexplained_limit(self) -> float:
        """The residual/floor ratio above which a discrepancy is unexplained: ``unexplained_ratio``, or, if higher,
        what noise alone exceeds with probability ``unexplained_false_alarm`` family-wise: the largest of ``m + 2``
        means of ``K`` squared unit-variance samples (chi-square with ``K`` degrees of freedom over ``K``; ``K``
        decimated samples)."""
        from scipy.stats import chi2
        K = self.tau.shape[1]
        alarm = self.settings.unexplained_false_alarm / (self.m + 2)
        return max(self.settings.unexplained_ratio, float(chi2.ppf(1.0 - alarm, K)) / K)

    def ratios(self) -> dict:
        """Residual energy over its noise floor (all samples: a fitted effect has 2-4 parameters against
        ~10 samples per second): per tendon, motor side and spring side."""
        mot = [float(np.mean((self.tau[i] / self.sigma_tau[i]) ** 2)) for i in range(self.m)]
        dof = self.m - self.n
        spr = [float(np.mean(self.eps[i] ** 2) * self.m / dof) for i in range(self.m)]
        return {"motor": mot, "spring": spr,
                "spring_total": float(np.mean(np.sum(self.eps ** 2, axis=0)) / dof),
                "joint": float(np.mean(np.sum(self.rho ** 2, axis=0)) / self.n) if self.joint_checked else
                float("nan")}


# ---------------------------------------------------------------------------- candidates
@dataclass
class Candidate:
    effect: str
    kind: str
    side: str
    tendon: int                 # 0-based
    label: str
    params: dict
    gain: float                 # held-out energy drop (noise units)
    z: float                    # held-out gain over its null spread
    delta_bic: float
    at_bound: list
    size: float                 # RMS of the fitted effect [N m] or [N]
    floor: float                # the noise-equivalent size it is compared with
    rejected: str = ""
    fitted: np.ndarray = field(default=None, repr=False)   # the effect's contribution to the residual
    loop: np.ndarray = field(default=None, repr=False)     # spring_hysteresis: the loop force [N] at the full rate


def hysteresis_loop(force: np.ndarray, law, h, force_noise: float, play: float, dt: float) -> np.ndarray:
    """The hysteresis force ``z`` [N] of one spring mechanism along a measured force record (full rate): the
    package's loop (:class:`~awiwi_drake.parameters.components.HysteresisParams`, the rate law
    :func:`~awiwi_drake.components.spring.hysteresis_rate`, level ``beta f + z0``, presliding length ``delta``)
    solved exactly per sample ``dt`` (:func:`~awiwi_drake.components.friction.dahl_path`) on the elongation the elastic
    law gives for the force, after a play operator of ``play`` force-noise widths (force noise must not reverse
    the loop: ``DiscrepancySettings.finger_hysteresis_play``). The level is taken at the measured force, which
    holds the loop itself: a relative level error of at most ``beta`` (the loop's half-width over the force)."""
    F = np.maximum(np.asarray(force, float), 1e-3)
    x = np.asarray(law.inverse_force(F), float)
    half = play * force_noise / float(np.median(np.asarray(law.stiffness(x), float)))
    return dahl_path(play_operator(x, half), h.width_ratio * F + h.width_offset, h.presliding_length,
                     h.smoothing_velocity, dt)


def _ripple_orders(fr: FingerResiduals, i: int, bounds: CatalogBounds) -> list:
    """Ripple order pairs to fit on motor ``i``: every order 1..``ripple_order_max`` is regressed alone
    (its sine and cosine through the consistent filter) on the training folds' residual; the two best orders,
    and the best with each of the next three, are the pairs."""
    from scipy.signal import oaconvolve
    th = fr.full["theta"][i]
    orders = np.arange(1, int(bounds.ripple_order_max) + 1, dtype=float)
    S = np.concatenate([np.sin(orders[:, None] * th[None]), np.cos(orders[:, None] * th[None])])
    cols = oaconvolve(S, fr._g0[None], mode="same", axes=1)[:, fr._sl]
    tr, O = fr.train, len(orders)
    y = fr.tau[i, tr]
    S, C = cols[:O, tr], cols[O:, tr]        # every order's sine and cosine column at once: the 2x2 normal
    G = np.stack([np.stack([np.sum(S * S, 1), np.sum(S * C, 1)], -1),            # equations per order
                  np.stack([np.sum(S * C, 1), np.sum(C * C, 1)], -1)], -2)      # (O, 2, 2)
    r = np.stack([S @ y, C @ y], -1)                                              # (O, 2)
    beta = np.einsum("kij,kj->ki", np.linalg.pinv(G), r)
    gains = np.einsum("ki,ki->k", beta, r) / fr.sigma_tau[i] ** 2      # explained energy b^T A (A^T A)^-1 A^T b
    rank = [float(orders[k]) for k in np.argsort(-gains)[:5]]
    return [(rank[0], rank[1])] + [(rank[0], o) for o in rank[2:]]


def _signatures(fr: FingerResiduals, effect: str, i: int, bounds: CatalogBounds):
    """Cached per dataset (:func:`_signature_variants`: the columns depend on the data, the settings (fixed per
    :class:`FingerResiduals`) and the catalog's bounds (the guide's capstan grid, the ripple orders), not on the
    residual left by earlier steps)."""
    key = (effect, i, bounds)
    if key not in fr._signature_cache:
        fr._signature_cache[key] = _signature_variants(fr, effect, i, bounds)
    return fr._signature_cache[key]


def _signature_variants(fr: FingerResiduals, effect: str, i: int, bounds: CatalogBounds):
    """Variants ``(label, columns (c, K), names, scale_to_params)`` of ``effect`` at tendon ``i`` (0-based):
    the residual model is ``columns.T @ beta``; motor side in N m, spring and joint sides whitened."""
    om, f = fr.omega[i], fr.force[i]
    thf = fr.full["theta"][i]
    H = fr.consistent
    out = []
    if effect == "motor_friction":   # (3.8): tau = -(g2 atan(g1 w) + g3 w): the missing torque adds to u
        for w in fr.settings.finger_motion_filters:
            omw = fr.motor_velocity(i, w)
            for slope in (3.0, 10.0, 30.0):
                out.append((f"slope {slope:g}, velocity filter {w * 1e3:g} ms",
                            np.stack([H(laws.motor_friction(omw, 1.0, slope, 0.0)),
                                      H(laws.motor_friction(omw, 0.0, slope, 1.0))]),
                            ["motor_coulomb", "motor_viscous"], {"motor_slope": slope, "motor_velocity_filter": w}))
    elif effect == "guide_friction":  # the joints feel -P_i^T g_i: the package's Dahl guides on path i, mu on a grid
        white = np.linalg.solve(fr._joint_whiten, -fr._P[i])[:, None]          # (n, 1)
        for w in fr.settings.finger_motion_filters:       # the travel's smoothing (FingerResiduals.guide_path)
            unit = white[None] * H(fr.guide_path(i, 1.0, 0.0, w))[None, None]        # (1, n, K): C = 1 N
            _, Dp, Dm = (H(c) for c in fr.guide_columns(i, w))
            for mu in np.linspace(0.0, bounds.guide_mu_max, 9)[1:]:
                cap = white[None] * (np.expm1(mu) * Dp - np.expm1(-mu) * Dm)[None, None]
                out.append((f"mu {mu:.3g}, path filter {w * 1e3:g} ms", np.concatenate([unit, cap]).reshape(2, -1),
                            ["guide_c0", "guide_capstan"], {"guide_mu": float(mu), "guide_path_filter": w}))
    elif effect == "motor_ripple":
        for o1, o2 in _ripple_orders(fr, i, bounds):
            cols, names = [], []
            for k, o in enumerate((o1, o2)):
                cols += [H(np.sin(o * thf)), H(np.cos(o * thf))]
                names += [f"ripple_sin{k + 1}", f"ripple_cos{k + 1}"]
            out.append((f"orders {o1:g}, {o2:g}", np.stack(cols), names,
                        {"ripple_order_1": o1, "ripple_order_2": o2}))
    elif effect == "nominal_motor":   # B error (acceleration), added damping: tau = -dB w' - dd w
        out.append(("", np.stack([-fr.acc_wide[i], -om]), ["motor_inertia_abs", "motor_damping_add"], {}))
    elif effect in SPRING_SIDE:
        e_i = fr.proj[:, :, i] * (fr.wsq[i] / fr.stiff[i])[:, None]     # (K, m): a force error on tendon i
        if effect == "spring_hysteresis":
            # the package's loop (HysteresisParams, Fig 4.8b): the Dahl law with level beta f + z0 on the elongation
            # (hysteresis_loop), linear in (beta, z0), at the full rate, then filtered (consistent): the finger's link
            # modes cycle the loop within a few samples, which a Dahl state of the filtered elongation would not see
            F = fr._force_raw[i]
            for length in fr.settings.finger_hysteresis_lengths:
                cols = [hysteresis_loop(F, fr.rig.spring_laws[i], HysteresisParams(width_ratio=a, width_offset=b,
                                                                                   presliding_length=length),
                                        fr.sig_force[i], fr.settings.finger_hysteresis_play, fr.dt)
                        for a, b in ((1.0, 0.0), (0.0, 1.0))]
                out.append((f"length {length:g} m", np.stack([(e_i * H(c)[:, None]).T for c in cols]),
                            ["hysteresis_ratio", "hysteresis_width"], {"hysteresis_length": length}))
        elif effect == "nominal_spring":
            out.append(("", (e_i * f[:, None]).T[None], ["spring_scale_rel"], {}))
        else:
            out.append(("", (e_i * 1.0).T[None], ["force_offset"], {}))
    return out


_BOUNDS = {"motor_coulomb": lambda b: (0.0, b.motor_coulomb_max), "motor_viscous": lambda b: (0.0, b.motor_viscous_max),
           "guide_c0": lambda b: (0.0, b.guide_c0_max), "guide_mu": lambda b: (0.0, b.guide_mu_max),
           "hysteresis_width": lambda b: (0.0, b.hysteresis_width_max),
           "hysteresis_ratio": lambda b: (0.0, b.hysteresis_ratio_max), "guide_capstan": lambda b: (0.0, np.inf)}
"""Physical ranges of the fitted amplitudes (``guide_capstan``: the scale of the capstan term at the grid's
``guide_mu``, 1 when the grid value is right)."""


def _lsq(A: np.ndarray, b: np.ndarray, names: list, bounds: CatalogBounds) -> np.ndarray:
    """Least squares with the catalog's physical ranges (friction levels >= 0, ...), solved exactly: the
    minimum of a convex quadratic over a box is the best feasible point among the unconstrained minima with each
    amplitude free or held at one of its finite bounds (3^c subproblems for c <= 4 columns)."""
    from itertools import product
    lo = np.array([_BOUNDS[n](bounds)[0] if n in _BOUNDS else -np.inf for n in names])
    hi = np.array([_BOUNDS[n](bounds)[1] if n in _BOUNDS else np.inf for n in names])
    best, best_cost = None, np.inf
    options = [[None] + [v for v in (lo[j], hi[j]) if np.isfinite(v)] for j in range(len(names))]
    for held in product(*options):
        beta = np.array([0.0 if h is None else h for h in held])
        free = [j for j, h in enumerate(held) if h is None]
        if free:
            beta[free] = np.linalg.lstsq(A[:, free], b - A @ beta, rcond=None)[0]
            if np.any(beta < lo - 1e-12 * np.abs(lo)) or np.any(beta > hi + 1e-12 * np.abs(hi)):
                continue
        cost = float(np.sum((b - A @ beta) ** 2))
        if cost < best_cost:
            best, best_cost = np.clip(beta, lo, hi), cost
    return best


def _fit(fr: FingerResiduals, effect: str, i: int, bounds: CatalogBounds, settings, base_motor, base_spring,
         base_joint):
    """Best variant of ``effect`` at tendon ``i``: blocked cross-validation (each fold held out once, fitted
    on the others): held-out gain, its null spread, and BIC of the fit on all data."""
    folds = fr.folds
    best = None
    for label, X, names, shape in _signatures(fr, effect, i, bounds):
        spring = effect in SPRING_SIDE or effect in JOINT_SIDE
        if spring:
            R = base_spring if effect in SPRING_SIDE else base_joint       # (m or n, K) whitened
            Xc = X.reshape(X.shape[0], R.shape[0], -1)                     # (c, m or n, K)
            design = lambda sel: Xc[:, :, sel].reshape(len(names), -1).T   # noqa: E731
            target = lambda sel: R[:, sel].ravel()                          # noqa: E731
            s = 1.0
        else:
            s = fr.sigma_tau[i]
            R, Xs = base_motor[i] / s, X / s
            design = lambda sel: Xs[:, sel].T                      # noqa: E731
            target = lambda sel: R[sel]                            # noqa: E731
        before, after = [], []
        for k in range(folds.max() + 1):
            te = folds == k
            beta = _lsq(design(~te), target(~te), names, bounds)
            b = target(te)
            before.append(b)
            after.append(b - design(te) @ beta)
        before, after = np.concatenate(before), np.concatenate(after)
        gain = float(before @ before - after @ after)
        z = gain_z(before, after)
        allk = np.ones_like(folds, dtype=bool)
        beta = _lsq(design(allk), target(allk), names, bounds)
        b = target(allk)
        e0, e1 = float(b @ b), float(np.sum((b - design(allk) @ beta) ** 2))
        n_obs = b.size
        dbic = n_obs * math.log(max(e1, 1e-300) / max(e0, 1e-300)) + len(names) * math.log(max(n_obs, 2))
        if spring:
            fit = np.tensordot(beta, Xc, axes=1)                   # (m or n, K)
            # the effect's size in newtons on its own tendon (before projection and whitening)
            f_i = fr.force[i]
            cols = {"spring_hysteresis": lambda: (beta[0] * f_i + beta[1]) * np.tanh(f_i),   # the half-width
                    "nominal_spring": lambda: beta[0] * f_i, "force_sensor": lambda: beta[0] * np.ones_like(f_i),
                    "guide_friction": lambda: beta[0] + beta[1] * (np.exp(shape.get("guide_mu", 0.0)) - 1) * f_i}
            size = float(np.sqrt(np.mean(cols[effect]() ** 2)))
            floor = float(fr.sig_force[i])
        else:
            fit = np.zeros_like(base_motor)
            fit[i] = beta @ X
            size = float(np.sqrt(np.mean((beta @ X) ** 2)))
            floor = float(fr.r * fr.sig_force[i])          # the torque the force-sensor noise exerts
        params = dict(zip(names, (float(v) for v in beta)))
        params.update(shape)
        side = "spring" if effect in SPRING_SIDE else "joint" if effect in JOINT_SIDE else "motor"
        c = Candidate(effect, "nuisance" if effect in NUISANCE else "physical", side, i,
                      label, params, gain, z, dbic, _at_bound(effect, params, bounds), size, floor, fitted=fit)
        if best is None or c.gain > best.gain:
            best = c
    if effect == "guide_friction":
        _guide_law_fit(fr, best, bounds, base_joint)
    return best


def _guide_law_fit(fr: FingerResiduals, c: Candidate, bounds: CatalogBounds, base_joint: np.ndarray) -> None:
    """The chosen guide candidate refitted as the package's law on all data: the capstan part's scale (free in
    the screen, whose two columns hold more than the law) fixed at 1 and its exponent ``mu alpha`` fitted
    (bounded scalar search), the constant by least squares for each exponent, so what is removed and written back
    (``tendon_guides``: constant and exponent) is one law; the screen's held-out gain and BIC decide acceptance."""
    from scipy.optimize import minimize_scalar
    i, w = c.tendon, c.params["guide_path_filter"]
    white = np.linalg.solve(fr._joint_whiten, -fr._P[i])[:, None]
    U, Dp, Dm = (white * fr.consistent(col)[None] for col in fr.guide_columns(i, w))
    R = base_joint
    c0_max = _BOUNDS["guide_c0"](bounds)[1]

    def best_c(E):
        rest = R - (np.expm1(E) * Dp - np.expm1(-E) * Dm)
        C = float(np.clip(np.sum(U * rest) / np.sum(U * U), 0.0, c0_max))
        return C, float(np.sum((rest - C * U) ** 2))

    E = float(minimize_scalar(lambda e: best_c(e)[1], bounds=(0.0, bounds.guide_mu_max), method="bounded",
                              options={"xatol": 1e-5}).x)
    # the bounded search never evaluates its ends (it stops ~xatol inside): an optimum at an end is that end, so
    # that at_bound sees an exponent resting on guide_mu_max
    E = min((E, 0.0, bounds.guide_mu_max), key=lambda e: best_c(e)[1])
    C = best_c(E)[0]
    c.params.update(guide_c0=C, guide_capstan=1.0, guide_mu=E)
    c.fitted = C * U + np.expm1(E) * Dp - np.expm1(-E) * Dm
    c.at_bound = _at_bound(c.effect, c.params, bounds)
    f_i = fr.force[i]
    c.size = float(np.sqrt(np.mean((C + np.expm1(E) * f_i) ** 2)))


def _hysteresis_law_fit(fr: FingerResiduals, c: Candidate, bounds: CatalogBounds, base_spring: np.ndarray,
                        named, rounds: int) -> float:
    """The accepted hysteresis candidate refitted as the package's loop on the finger's own motion, what is
    written back (the screen's columns run the Dahl law on the noisy measured elongation, which biases the fit).
    The elongation is the finger replayed on the recorded commands (:meth:`FingerResiduals.replay` of ``named``,
    the dataset's parameters with the effects named so far written in, and this loop): the loop
    ``beta f_el(x) + z0`` (``spring.hysteresis_rate``, solved per sample by
    :func:`~awiwi_drake.components.friction.dahl_path`) is linear in ``(beta, z0)`` along it, fitted by bounded
    least squares to the spring-side residual for each presliding length (the grid, then a bounded search on
    ``log delta`` around the best), and the replay repeats with the new loop until the parameters settle (1 %),
    ``rounds`` replays at most. Kept: the loop that, judged on its own replay's motion, leaves the least (a refit
    is judged on the motion of the loop before it). ``c`` is updated (parameters, the loop force along its
    replay's elongation, size, ``at_bound``); returns the energy the last refit leaves on its replay's motion (how
    the tendons of a class compare after one replay)."""
    from scipy.optimize import minimize_scalar
    i, s = c.tendon, fr.settings
    law, grid = fr.rig.spring_laws[i], np.asarray(s.finger_hysteresis_lengths, float)
    e_i = fr.proj[:, :, i] * (fr.wsq[i] / fr.stiff[i])[:, None]
    names, R = ["hysteresis_ratio", "hysteresis_width"], base_spring.ravel()
    h = HysteresisParams(enabled=True, width_ratio=max(c.params["hysteresis_ratio"], 0.0),
                         width_offset=max(c.params["hysteresis_width"], 0.0),
                         presliding_length=c.params["hysteresis_length"])
    best = None
    for _ in range(rounds):
        x = fr.replay(with_loop(named, fr.rig.tendon_names[i], h))["elongation"][i]
        fel = np.asarray(law.force(x), float)

        def columns(length):
            return np.stack([(e_i * fr.consistent(dahl_path(x, lv, length, h.smoothing_velocity, fr.dt))[:, None]).T.ravel()
                             for lv in (fel, np.ones_like(fel))]).T

        def fit(length):
            X = columns(length)
            beta = _lsq(X, R, names, bounds)
            return float(np.sum((R - X @ beta) ** 2)), beta

        # the loop this replay ran with, judged on its own motion: what a reload of it leaves
        left = float(np.sum((R - columns(h.presliding_length) @ [h.width_ratio, h.width_offset]) ** 2))
        if best is None or left < best[0]:
            best = (left, h, x, fel)
        k = int(np.argmin([fit(d)[0] for d in grid]))
        lo, hi = np.log(grid[max(k - 1, 0)]), np.log(grid[min(k + 1, len(grid) - 1)])
        length = float(np.exp(minimize_scalar(lambda u: fit(np.exp(u))[0], bounds=(lo, hi), method="bounded",
                                              options={"xatol": 0.01}).x)) if hi > lo else float(grid[k])
        refit, beta = fit(length)
        new = h.replace(width_ratio=float(beta[0]), width_offset=float(beta[1]), presliding_length=length)
        settled = np.allclose([new.presliding_length, new.width_ratio * np.mean(fel) + new.width_offset],
                              [h.presliding_length, h.width_ratio * np.mean(fel) + h.width_offset], rtol=0.01)
        h = new
        if settled:
            break
    _, h, x, fel = best
    c.loop = dahl_path(x, h.width_ratio * fel + h.width_offset, h.presliding_length, h.smoothing_velocity, fr.dt)
    c.params.update(hysteresis_ratio=h.width_ratio, hysteresis_width=h.width_offset,
                    hysteresis_length=h.presliding_length)
    c.at_bound = _at_bound(c.effect, c.params, bounds)
    f_i = fr.force[i]
    c.size = float(np.sqrt(np.mean(((h.width_ratio * f_i + h.width_offset) * np.tanh(f_i)) ** 2)))
    return refit


def _refit_loop(fr: FingerResiduals, same: list, bounds: CatalogBounds, base_spring, named, settings) -> Candidate:
    """The hysteresis candidates ``same`` (the screen's equals, on different tendons) refitted on the replayed finger
    (:func:`_hysteresis_law_fit`): one replay each, the one that leaves the least refitted to the end."""
    left = {id(c): _hysteresis_law_fit(fr, c, bounds, base_spring, named, 1) for c in same}
    c = min(same, key=lambda c: left[id(c)])
    _hysteresis_law_fit(fr, c, bounds, base_spring, named, settings.finger_hysteresis_refits)
    return c


def _swap_member(members: list, c: Candidate, new_place: str, old_place: str) -> list:
    """A class's members after its member ``c`` (at ``new_place``) is named first instead of ``old_place``."""
    swap = {f"{c.effect} on {new_place}": f"{c.effect} on {old_place}"}
    return [members[0]] + [swap.get(mb, mb) for mb in members[1:]]


def _at_bound(effect: str, p: dict, bounds: CatalogBounds) -> list:
    """Amplitudes resting on the upper end of their physical range (a bound is not an estimate); the lower
    end 0 is the term switched off, which the materiality test judges."""
    return [k for k, v in p.items() if k in _BOUNDS and v >= _BOUNDS[k](bounds)[1] * (1 - 1e-9)]


def _reject(c: Candidate, settings: DiscrepancySettings) -> str:
    if c.z < settings.min_z:
        return f"held-out gain {c.z:.1f} null std < min_z {settings.min_z:g}"
    if c.delta_bic >= 0:
        return f"BIC not better than without it (dBIC {c.delta_bic:.1f})"
    if c.at_bound:
        return f"outside the physical range: {', '.join(c.at_bound)}"
    if c.size < settings.finger_material * c.floor:
        return (f"not material: effect RMS {c.size:.3g} < {settings.finger_material:g} x noise-equivalent "
                f"{c.floor:.3g}")
    return ""


# ---------------------------------------------------------------------------- result
@dataclass
class FingerStep:
    effect: str
    kind: str
    place: str
    tendon: int                 # 1-based
    status: str                 # confirmed | not separable
    parameters: dict
    members: list
    experiment: str
    z: float
    delta_bic: float


@dataclass
class FingerDiagnosis:
    dataset: str
    rig: str
    steps: list
    ratios_before: dict
    ratios_after: dict
    unexplained_residual: bool
    unexplained: dict
    verdict: str
    seconds: float
    cpu_seconds: float
    history: list
    tendon_names: list
    unexplained_ratio: float
    unused_columns: list = field(default_factory=list)   # recorded but not used (joint angles)
    complete: bool = True
    augmented: AugmentedParameters | None = None   # the dataset's FingerRigParams with the named effects written
    finger: str = ""
    joint_checked: bool = True      # False on thumb, ring, fifth: the links' equation (guide friction) is not judged
    joint_reason: str = ""
    warnings: list = field(default_factory=list)   # e.g. windows where the thumb's joint angles did not converge

    @property
    def named_effects(self) -> list:
        return [s.effect for s in self.steps if s.kind == "physical"]

    @property
    def nuisance_corrections(self) -> list:
        return [s.effect for s in self.steps if s.kind == "nuisance"]

    @property
    def places(self) -> dict:
        """``{effect: place}`` of the named physical effects; an effect named on several tendons keeps every
        place, in the order named, joined by ``" and "`` (:attr:`tendons_named` has them as lists)."""
        return {e: " and ".join(s.place for s in self.steps if s.kind == "physical" and s.effect == e)
                for e in self.named_effects}

    @property
    def tendons_named(self) -> dict:
        """``{effect: [tendon names]}`` of the named physical effects (every tendon each was named on)."""
        out: dict = {}
        for s in self.steps:
            if s.kind == "physical":
                out.setdefault(s.effect, []).append(self.tendon_names[s.tendon - 1])
        return out

    def summary(self) -> dict:
        """The JSON summary (``diagnose --json``)."""
        return {"dataset": self.dataset, "rig": self.rig, "verdict": self.verdict, "complete": self.complete,
                "named_effects": self.named_effects, "places": self.places,
                "nuisance_corrections": self.nuisance_corrections,
                "steps": [asdict(s) for s in self.steps],
                "floor_ratio_before": self.ratios_before, "floor_ratio_after": self.ratios_after,
                "unexplained_residual": self.unexplained_residual, "unexplained": self.unexplained,
                "seconds": self.seconds, "cpu_seconds": self.cpu_seconds, "history": self.history,
                "unused_columns": self.unused_columns, "joint_side_checked": self.joint_checked,
                "warnings": self.warnings,
                "augmented": None if self.augmented is None else {
                    "parameters": finger_parameters_to_json(self.finger, self.augmented.params),
                    "applied": self.augmented.applied, "not_representable": self.augmented.not_representable}}

    def text(self) -> str:
        lines = [f"{self.dataset}: {self.verdict}"]
        if self.joint_reason:       # a finger whose links' equation is not judged; the hand: those fingers
            where = "these fingers of the hand" if self.finger == "hand" else f"the {self.finger}"
            lines.append(f"  joint side not judged on {where} (guide friction is not looked for): {self.joint_reason}")
        lines += [f"  warning: {w}" for w in self.warnings]
        if self.unused_columns:
            lines.append(f"  not used: {', '.join(self.unused_columns)} (joint angles are estimated from the tendons)")
        for s in self.steps:
            ps = ", ".join(f"{k} = {v:.4g}" for k, v in s.parameters.items())
            lines.append(f"  {s.effect} on {s.place} [{s.status}]: {ps}")
            if s.status == "not separable":
                lines.append(f"    not separable with these data from {', '.join(s.members[1:])}; to separate "
                             f"them: {s.experiment}")
        if self.unexplained_residual:
            lines.append(f"  unexplained: {self.unexplained['text']}")
        if self.augmented is not None and self.augmented.applied:
            lines.append(f"  written into the finger's parameters (tendon_motors, tendon_springs, tendon_guides): {', '.join(self.augmented.applied)}")
        if self.augmented is not None and self.augmented.not_representable:
            lines.append(f"  not representable in FingerRigParams: {'; '.join(self.augmented.not_representable)}")
        return "\n".join(lines)


def _verdict(steps: list, unexplained: bool) -> str:
    named = [f"{s.effect} on {s.place}" for s in steps if s.kind == "physical"]
    if unexplained:
        return "unexplained discrepancy remains" + (f" after {', '.join(named)}" if named else "")
    if named:
        return "found " + ", ".join(named)
    if steps:
        return "calibration only: " + ", ".join(f"{s.effect} on {s.place}" for s in steps)
    return "no discrepancy above the noise floor"


def hand_fingers(dataset: Dataset):
    """``[(finger, tendon slice, FingerCoupling, finger Dataset)]``: a hand dataset as its five fingers' (columns
    renumbered in each finger's order, the finger's ``FingerRigParams`` from the hand's with its own tendons'
    entries)."""
    import dataclasses as dc

    from awiwi_drake.hand.coupling import finger_coupling
    from awiwi_drake.parameters.hand import FINGERS, TENDON_SLICES, FingerDriveParams, FingerRigParams

    from .data import finger_rig_name
    hp = finger_parameters_from_json(dataset.parameters, dataset.name)
    drive = {f.name: getattr(hp, f.name) for f in dc.fields(FingerDriveParams)}
    out, j0 = [], 0
    for f in FINGERS:
        sl, c = TENDON_SLICES[f], finger_coupling(f, hp.hand.finger(f))
        own = set(hp.tendon_names[sl])
        fp = FingerRigParams(finger=hp.hand.finger(f), finger_name=f, **dict(
            drive, **{k: tuple((t, v) for t, v in drive[k] if t in own)
                      for k in ("tendon_motors", "tendon_springs", "tendon_guides")}))
        cols = lambda src, kind, first, count: {f"{kind}_{k + 1}": src[f"{kind}_{first + k + 1}"]  # noqa: E731
                                                for k in range(count) if f"{kind}_{first + k + 1}" in src}
        outputs = {**cols(dataset.outputs, "motor_angle", sl.start, c.num_tendons),
                   **cols(dataset.outputs, "tendon_force", sl.start, c.num_tendons),
                   **cols(dataset.outputs, "joint_angle", j0, c.num_joints)}
        out.append((f, sl, c, Dataset(f"{dataset.name}[{f}]", finger_rig_name(f), dataset.time,
                                      cols(dataset.inputs, "motor_torque", sl.start, c.num_tendons), outputs,
                                      finger_parameters_to_json(f, fp), {}, {})))
        j0 += c.num_joints
    return out


def _diagnose_hand(dataset: Dataset, settings, bounds, say) -> FingerDiagnosis:
    """The hand (rig ``hand``): its routing is block-diagonal by finger (each tendon moves its own finger's joints
    only; the hand's fingers are independent chains on the palm, the wrist still), so the hand's motor, spring and
    links' equations are the five fingers' and the diagnosis is the five finger diagnoses, joined: steps and
    ratios per tendon in the hand's order (thumb 1-8, index 9-16, middle 17-24, ring 25-30, fifth 31-38), the
    spring and links' ratios pooled over the fingers' degrees of freedom, the write-back one ``HandRigParams``."""
    import dataclasses as dc

    hp = finger_parameters_from_json(dataset.parameters, dataset.name)
    parts = {f: (sl, c, diagnose_finger(sub, settings=settings, bounds=bounds,
                                        progress=lambda msg, f=f: say(f"{f}: {msg}")))
             for f, sl, c, sub in hand_fingers(dataset)}
    steps = [dc.replace(st, tendon=sl.start + st.tendon) for sl, _, d in parts.values() for st in d.steps]

    def pooled(ratios, key, weight):
        w = {f: weight(c) for f, (_, c, d) in parts.items() if np.isfinite(getattr(d, ratios)[key])}
        return float(sum(getattr(parts[f][2], ratios)[key] * w[f] for f in w) / sum(w.values())) if w else \
            float("nan")

    def ratios(which):
        return {"motor": [v for _, _, d in parts.values() for v in getattr(d, which)["motor"]],
                **({"spring": [v for _, _, d in parts.values() for v in d.ratios_before["spring"]]}
                   if which == "ratios_before" else {}),
                "spring_total": pooled(which, "spring_total", lambda c: c.num_tendons - c.num_joints),
                "joint": pooled(which, "joint", lambda c: c.num_joints)}

    worse = {f: d.unexplained for f, (_, _, d) in parts.items() if d.unexplained_residual}
    unexplained = {"fingers": worse, "text": "; ".join(f"{f}: {u['text']}" for f, u in worse.items())} if worse else {}
    fingers = [d for _, _, d in parts.values()]
    augmented = AugmentedParameters(
        hp.replace(**{k: tuple(t for d in fingers for t in getattr(d.augmented.params, k))
                      for k in ("tendon_motors", "tendon_springs", "tendon_guides")}),
        [a for d in fingers for a in d.augmented.applied],
        [a for d in fingers for a in d.augmented.not_representable])
    return FingerDiagnosis(
        dataset.name, dataset.rig, steps, ratios("ratios_before"), ratios("ratios_after"), bool(worse), unexplained,
        _verdict(steps, bool(worse)), sum(d.seconds for d in fingers), sum(d.cpu_seconds for d in fingers),
        [dict(h, finger=f) for f, (_, _, d) in parts.items() for h in d.history], list(hp.tendon_names),
        settings.unexplained_ratio, [k for k in dataset.output_names if k.startswith("joint_angle")],
        all(d.complete for d in fingers), augmented, "hand", any(d.joint_checked for d in fingers),
        "; ".join(f"{f}: {d.joint_reason}" for f, (_, _, d) in parts.items() if not d.joint_checked),
        [f"{f}: {w}" for f, (_, _, d) in parts.items() for w in d.warnings])


def diagnose_finger(dataset: Dataset, *, settings: DiscrepancySettings | None = None,
                    bounds: CatalogBounds | None = None, progress=None) -> FingerDiagnosis:
    """Localise the discrepancy of a finger dataset to tendons and name effect and place (module docstring);
    the hand's dataset as its five fingers' (:func:`_diagnose_hand`)."""
    settings = settings or DiscrepancySettings()
    bounds = bounds or CatalogBounds()
    say = progress or (lambda msg: None)
    if dataset.rig == "hand":
        return _diagnose_hand(dataset, settings, bounds, say)
    t0, c0 = time.perf_counter(), time.process_time()
    fr = FingerResiduals(dataset, settings)
    places = [tendon_place(fr.rig, i) for i in range(fr.m)]
    unused = [k for k in dataset.output_names if k.startswith("joint_angle")]
    if unused:   # said, not silently dropped
        say(f"note: {', '.join(unused)} recorded but not used: the joint angles are estimated from the tendons "
            f"(as on the hand, which has no joint sensors)")
    before = fr.ratios()
    say(f"{dataset.name}: {fr.finger} finger, {fr.m} tendons, {len(dataset.time)} samples "
        f"({fr.tau.shape[1]} filtered, {int(fr.test.sum())} held out)")
    say("motor side, residual/floor per tendon: " + ", ".join(f"{v:.2f}" for v in before["motor"]))
    say("spring side, residual/floor per tendon: " + ", ".join(f"{v:.2f}" for v in before["spring"])
        + f" (all: {before['spring_total']:.2f})")
    base_motor, base_spring, base_joint = fr.tau.copy(), fr.eps.copy(), fr.rho.copy()
    if fr.joint_checked:
        say(f"joint side (links' equation, guide friction), residual/floor: {before['joint']:.2f}")
    steps, history, used = [], [], set()
    floor = settings.floor_ratio
    # the thumb (routing h(q) nonlinear): its spring side is judged, its links' equation is not (joint side)
    if not fr.joint_checked:
        say(f"joint side not judged on the {fr.finger} (no guide friction): {fr.joint_reason}")
    warnings = []
    if fr.not_converged:
        warnings.append(
            f"joint angles from the tendons did not converge in {settings.finger_gauss_newton_iterations} "
            f"Gauss-Newton steps (DiscrepancySettings.finger_gauss_newton_iterations) in "
            + ", ".join(f"t = {a:.3f}-{b:.3f} s" for a, b in fr.not_converged[:5])
            + (f" and {len(fr.not_converged) - 5} more windows" if len(fr.not_converged) > 5 else "")
            + ": the spring-side residual there is not the routing's")
        say("warning: " + warnings[-1])

    def current():
        mot = [float(np.mean((base_motor[i] / fr.sigma_tau[i]) ** 2)) for i in range(fr.m)]
        spr = float(np.mean(np.sum(base_spring ** 2, axis=0)) / (fr.m - fr.n))
        jnt = float(np.mean(np.sum(base_joint ** 2, axis=0)) / fr.n) if fr.joint_checked else 0.0
        return mot, spr, jnt

    n_phys = n_nuis = 0
    loops: dict = {}        # step index -> [the accepted hysteresis candidate (loop removed), its equals]
    refitted: set = set()   # step indices whose loop was refitted when named
    while True:
        mot, spr, jnt = current()
        if max(mot) < floor and spr < floor and jnt < floor:
            stop = "residual at the noise floor"
            break
        cands = []
        for eff in MOTOR_SIDE + SPRING_SIDE + JOINT_SIDE:
            kind = "nuisance" if eff in NUISANCE else "physical"
            if (kind == "physical" and n_phys >= settings.max_effects) or \
                    (kind == "nuisance" and n_nuis >= settings.max_nuisance):
                continue
            for i in range(fr.m):
                if (eff, i) in used or (mot[i] if eff in MOTOR_SIDE else spr if eff in SPRING_SIDE else jnt) < floor:
                    continue
                c = _fit(fr, eff, i, bounds, settings, base_motor, base_spring, base_joint)
                c.rejected = _reject(c, settings)
                cands.append(c)
        cands.sort(key=lambda c: -c.gain)
        history.append({"screen": [dict(effect=c.effect, place=places[c.tendon], gain=c.gain, z=c.z,
                                        delta_bic=c.delta_bic, rejected=c.rejected) for c in cands[:8]]})
        say("candidates: " + "; ".join(f"{c.effect} on {fr.rig.tendon_names[c.tendon]} z {c.z:.1f}"
                                        + (f" ({c.rejected})" if c.rejected else "") for c in cands[:4]))
        passing = [c for c in cands if not c.rejected]
        if not passing:
            stop = "no candidate passes the acceptance tests"
            break
        win = passing[0]
        # the simpler explanation: a calibration that explains as much wins over a physical effect
        nuis = [c for c in passing if c.kind == "nuisance" and c.gain >= settings.ambiguous_ratio * win.gain]
        if win.kind == "physical" and nuis:
            win = nuis[0]
        tied = [c for c in passing if c is not win and c.kind == win.kind
                and c.gain >= settings.ambiguous_ratio * win.gain and c.side == win.side]
        status, members, experiment = "confirmed", [win.effect], ""
        if tied:
            members = [win.effect] + [f"{c.effect}" + ("" if c.tendon == win.tendon else f" on {places[c.tendon]}")
                                      for c in tied]
            status = "not separable"
            others = sorted({c.effect for c in tied} - {win.effect})
            experiment = separating_experiment([win.effect] + others) if others else ""
            same = [fr.rig.tendon_names[c.tendon] for c in tied if c.effect == win.effect and c.tendon != win.tendon]
            if same:    # one effect, two places: tell the tendons apart, not the effects
                pair = ", ".join([fr.rig.tendon_names[win.tendon]] + same)
                how = (f"slide the joint with one tendon of the pair tensioned at a time ({pair}): the capstan part "
                       f"follows the loaded tendon" if win.effect == "guide_friction" else
                       f"hold the joints and cycle one tendon's force at a time ({pair}): the effect follows its "
                       f"own tendon")
                experiment = "; ".join(x for x in (experiment, how) if x)
        if win.side == "motor":
            base_motor = base_motor - win.fitted
        elif win.effect == "spring_hysteresis":   # removed as a nominal loop is (not linearised): refitted on the
            # replayed finger now if every motor law holds (the replay drives the motors by them), else the screen's
            # loop until every effect is named (below); a loop left as the screen fitted it invites calibrations
            # that fit its error
            same = [win] + [c for c in tied if c.effect == win.effect]
            if max(current()[0]) < fr.unexplained_limit():     # the motor sides at noise: the motor laws hold
                named = augmented_finger_parameters(SimpleNamespace(steps=steps, tendon_names=fr.rig.tendon_names),
                                                    fr.params).params
                try:
                    c = _refit_loop(fr, same, bounds, base_spring, named, settings)
                except SimulationDivergedError as exc:
                    say(f"note: the finger replay of {fr.ds.name}: {exc}; the refit waits until every effect is "
                        f"named")
                else:
                    refitted.add(len(steps))
                    if c is not win:
                        members = _swap_member(members, c, places[c.tendon], places[win.tendon])
                        win, same = c, [c] + [x for x in same if x is not c]
            if win.loop is None:
                g = win.params
                win.loop = hysteresis_loop(fr._force_raw[win.tendon], fr.rig.spring_laws[win.tendon],
                                           HysteresisParams(enabled=True, width_ratio=g["hysteresis_ratio"],
                                                            width_offset=g["hysteresis_width"],
                                                            presliding_length=g["hysteresis_length"]),
                                           fr.sig_force[win.tendon], settings.finger_hysteresis_play, fr.dt)
            base_spring = base_spring - fr.loop_removed(win.tendon, win.loop)
            loops[len(steps)] = same
        elif win.side == "joint":
            base_joint = base_joint - win.fitted
        else:
            base_spring = base_spring - win.fitted
        used.add((win.effect, win.tendon))
        n_phys += win.kind == "physical"
        n_nuis += win.kind == "nuisance"
        steps.append(FingerStep(win.effect, win.kind, places[win.tendon], win.tendon + 1, status, win.params,
                                members, experiment, win.z, win.delta_bic))
        say(f"added {win.effect} on {places[win.tendon]} ({win.kind}, {status}, z {win.z:.1f}, "
            f"dBIC {win.delta_bic:.1f}): " + ", ".join(f"{k} = {v:.4g}" for k, v in win.params.items()))
    # the write-back's loops: refitted on the finger replayed with every other named effect (_hysteresis_law_fit; a
    # motor friction left out moves the replay's motor), on the tendon of the screen's equals where the refit leaves
    # the least (the screen's columns cannot tell antagonists apart)
    for k, same in loops.items():
        if k in refitted and k == len(steps) - 1:      # refitted with every other effect already named
            continue
        others = augmented_finger_parameters(SimpleNamespace(steps=steps[:k] + steps[k + 1:],
                                                             tendon_names=fr.rig.tendon_names), fr.params).params
        without = base_spring + fr.loop_removed(same[0].tendon, same[0].loop)
        try:
            c = _refit_loop(fr, same, bounds, without, others, settings)
        except SimulationDivergedError as exc:     # said, and the loop kept
            warnings.append(f"the finger replay of {fr.ds.name}: {exc}: spring_hysteresis on {steps[k].place} is "
                            f"written as the screen fitted it (on the measured force's elongation, whose noise "
                            f"biases it)")
            say("warning: " + warnings[-1])
            continue
        base_spring = without - fr.loop_removed(c.tendon, c.loop)
        st = steps[k]
        if c.tendon != st.tendon - 1:     # the class's member the replay prefers: named first, the other a member
            st.members = _swap_member(st.members, c, places[c.tendon], st.place)
            st.tendon, st.place = c.tendon + 1, places[c.tendon]
        st.parameters = c.params
        say(f"spring_hysteresis on {st.place} refitted on the replayed finger: "
            + ", ".join(f"{key} = {v:.4g}" for key, v in c.params.items()))
    mot, spr, jnt = current()
    after = {"motor": mot, "spring_total": spr,
             "joint": jnt if fr.joint_checked else float("nan")}
    limit = fr.unexplained_limit()
    worst = max(max(mot), spr, jnt)
    unexplained = worst > limit
    where = {}
    if unexplained:
        tendons = [places[i] for i in range(fr.m) if mot[i] > limit]
        where = {"motor_side": tendons, "spring_side": spr > limit, "joint_side": jnt > limit,
                 "text": (f"held-out residual up to {worst:.2f}x the noise floor"
                          + (f" on the motor side of {', '.join(tendons)}" if tendons else "")
                          + (f"; spring side {spr:.2f}x" if spr > limit else "")
                          + (f"; joint side (links' equation) {jnt:.2f}x" if jnt > limit else ""))}
    verdict = _verdict(steps, unexplained)
    say(f"{stop}: {verdict}")
    dx = FingerDiagnosis(dataset.name, dataset.rig, steps, before, after, unexplained, where, verdict,
                         time.perf_counter() - t0, time.process_time() - c0, history, list(fr.rig.tendon_names),
                         settings.unexplained_ratio, unused, finger=fr.finger, joint_checked=fr.joint_checked,
                         joint_reason=fr.joint_reason,
                         warnings=warnings)
    dx.augmented = augmented_finger_parameters(dx, fr.params)
    return dx
