"""Replay measured commands through the augmented model: multiple-shooting windows.

The dataset is cut into windows of ``settings.window`` seconds.  Each window
starts from the state estimated from the measurements (smoothed angles,
Savitzky-Golay velocities, link angle measured or recovered from the forces)
and is simulated open loop with the logged commands, so drift of the free
joint chain cannot build up beyond one window.  The remaining sensitivity to
the uncertain window-start state is removed by projecting every window's
residual onto the orthogonal complement of its initial-state sensitivities
(a linearised profile over the window initial states, i.e. multiple shooting
with free shooting nodes).

All windows and all perturbed parameter sets of one evaluation are copies of
one :class:`~awiwi_drake.discrepancy.model.DiscrepancyModel_`, integrated by
one Drake ``Simulator`` (fixed-step RK3, built once per batch size and reset).
Independent jobs (the simulation fits of one step's candidates) run side by side with
their replays merged into one pass (:meth:`ReplayEngine.run_batched`).
"""

from __future__ import annotations

import threading
import time

import numpy as np
from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
from scipy.signal import savgol_coeffs, savgol_filter

from awiwi_drake.analysis import SimulationDivergedError
from awiwi_drake.parameters.discrepancy import DiscrepancySettings

from . import laws
from .catalog import PARAM_INDEX
from .data import Dataset
from .model import DiscrepancyModel_, NominalParameters

__all__ = ["ReplayEngine", "Projection", "project", "noise_floor", "play_operator"]


def noise_floor(y: np.ndarray) -> float:
    """White-noise standard deviation of a sampled signal, from its 3rd differences.

    For a smooth signal plus white noise of variance s^2, the third difference
    has variance 20 s^2 while the signal contributes (w dt)^3 of its amplitude;
    the median absolute deviation makes the estimate robust to steps.
    """
    d3 = np.diff(np.asarray(y, float), 3)
    if d3.size == 0:
        return 0.0
    mad = np.median(np.abs(d3 - np.median(d3))) * 1.4826
    return float(mad / np.sqrt(20.0))


def play_operator(x: np.ndarray, half_width: float) -> np.ndarray:
    """Play operator (Prandtl-Ishlinskii stop) of half-width ``half_width``: the output follows ``x`` only once it
    leaves ``[y - h, y + h]`` (noise smaller than the play does not reverse a loop's direction)."""
    y, out = float(x[0]), np.empty_like(x)
    for k, v in enumerate(x.tolist()):
        y = min(max(y, v - half_width), v + half_width)
        out[k] = y
    return out


class ReplayEngine:
    """Multiple-shooting replay of one dataset (see module docstring).

    Parameters
    ----------
    dataset : Dataset
    settings : DiscrepancySettings, optional
    """

    def __init__(self, dataset: Dataset, settings: DiscrepancySettings | None = None):
        self.ds = dataset
        self.settings = settings or DiscrepancySettings()
        self.nom = NominalParameters.from_dataset(dataset.rig, dataset.parameters)
        self.dt = dataset.dt
        self.U = dataset.input_matrix  # (N, n)
        N = len(dataset.time)
        self.N = N
        L = int(round(self.settings.window / self.dt))
        if L < 3:
            raise ValueError(f"settings.window = {self.settings.window} s is shorter than 3 samples "
                             f"of {dataset.name} (dt = {self.dt} s)")
        if N < L + 2:
            raise ValueError(f"dataset {dataset.name}: {N} samples are fewer than one "
                             f"{self.settings.window} s window")
        self.L = L
        self.starts = np.arange(0, N - L - 1, L)
        blk = max(1, int(round(self.settings.block / self.settings.window)))
        block_id = np.arange(len(self.starts)) // blk
        self.test = (block_id % 2) == 1
        if not self.test.any():  # short record: alternate windows
            self.test = (np.arange(len(self.starts)) % 2) == 1
        self.train = ~self.test
        # measured signals, model measurement mapping, noise floor
        model_names = self.nom.measurement_names()
        self.out_names = dataset.output_names
        self.out_index = np.array([model_names.index(o) for o in self.out_names])
        self.Y = np.column_stack([dataset.outputs[o] for o in self.out_names])  # (N, ny)
        sig = np.array([noise_floor(self.Y[:, j]) for j in range(self.Y.shape[1])])
        spread = self.Y.std(axis=0)
        self.sigma = np.maximum(sig, 1e-6 * np.maximum(spread, 1e-12))
        self.spread = np.maximum(spread, 1e-12)
        self._estimate_states()
        self._sims = {}
        self._local = threading.local()   # the merged replays of :meth:`run_batched`, per job thread
        self._dahl_cache = {}
        self._played = None
        self.simulations = 0
        self.sim_time = 0.0

    # ------------------------------------------------------------------ states
    def _estimate_states(self):
        ds, nom, dt = self.ds, self.nom, self.dt
        n = nom.num_motors
        sfx = ["_1", "_2"] if n == 2 else [""]
        th = np.array([ds.outputs[f"motor_angle{s}"] for s in sfx])
        # differentiation window grows with the relative angle noise (sqrt law: velocity
        # noise ~ 1/T^1.5, smoothing bias ~ T^2), capped at half a shooting window
        rel = max(noise_floor(row) / max(row.std(), 1e-12) for row in th)
        T = self.settings.velocity_smoothing * max(1.0, np.sqrt(rel / 0.01))
        T = min(T, 0.5 * self.settings.window)
        win = max(5, int(round(T / dt)) | 1)
        win = min(win, (self.N // 2) * 2 - 1)
        self._sg_window = win
        ths = savgol_filter(th, win, 3, axis=1)
        om = savgol_filter(th, win, 3, deriv=1, delta=dt, axis=1)
        cols = [ths, om]
        if nom.has_link:
            q = self._joint_angle_estimate(ths)
            self._q_raw = q
            qs = savgol_filter(q, win, 3)
            qd = savgol_filter(q, win, 3, deriv=1, delta=dt)
            cols += [qs[None], qd[None]]
        self.xhat = np.vstack(cols)  # (ns - n, N), rows [theta, omega, (q, q')]
        self.xpos = xhat_positions(nom)  # model-state index of each xhat row
        x, xd = laws_kinematics(nom, self.xhat)
        self.elong = np.array(x)  # (n, N)
        self._elong_rate_max = float(np.max(np.abs(xd)))
        forces = [np.max(np.abs(ds.outputs[k])) for k in ds.outputs if k.startswith("tendon_force")]
        self._force_max = float(max(forces)) if forces else float(laws.spring_force(np.max(self.elong),
                                                                                     nom.spring_poly))

    def _joint_angle_estimate(self, ths):
        ds, nom = self.ds, self.nom
        if "joint_angle" in ds.outputs:
            return np.asarray(ds.outputs["joint_angle"], float)
        r, rq = nom.motor_pulley_radius, nom.link_pulley_radius
        est = []
        xs = np.linspace(0.0, 0.05, 4001)
        fs = laws.spring_force(xs, nom.spring_poly)
        for i, s in enumerate(("_1", "_2")):
            key = f"tendon_force{s}"
            if key in ds.outputs:
                x = np.interp(ds.outputs[key], fs, xs)
                est.append((r * ths[0] - x) / rq if i == 0 else (x - r * ths[1]) / rq)
        if est:
            return np.mean(est, axis=0)
        return r * (ths[0] - ths[1]) / (2 * rq)

    def _played_elongation(self) -> np.ndarray:
        """Elongation through a play operator of half-width three times its noise
        (Prandtl-Ishlinskii stop): sensor noise on the smoothed elongation would
        otherwise reverse the direction every few samples and wash out the Dahl state."""
        if self._played is None:
            nom, n = self.nom, self.nom.num_motors
            g0 = float(np.sqrt(np.sum(savgol_coeffs(self._sg_window, 3) ** 2)))
            sfx = ["_1", "_2"] if n == 2 else [""]
            sig = [nom.motor_pulley_radius * self.sigma[self.out_names.index(f"motor_angle{s}")] for s in sfx]
            if nom.has_link:
                sig = [float(np.hypot(v, nom.link_pulley_radius * noise_floor(self._q_raw))) for v in sig]
            self._played = np.stack([play_operator(self.elong[i], 3.0 * g0 * sig[i]) for i in range(n)])
        return self._played

    def _dahl_history(self, length: float, initial: float = 0.0) -> np.ndarray:
        """Normalised Dahl state ``w/h`` (num_motors, N) at every sample, run on the
        (play-filtered, smoothed) elongation from ``w = initial`` at the dataset start."""
        key = (float(length), float(initial))
        hit = self._dahl_cache.get(key)
        if hit is not None:
            return hit
        dx = np.diff(self._played_elongation(), axis=1)
        n, N = self.elong.shape
        w = np.zeros((n, N))
        for i in range(n):
            a = np.exp(-np.abs(dx[i]) / key[0]).tolist()
            sg = np.sign(dx[i]).tolist()
            wi = key[1]
            out = [wi]
            for ak, sk in zip(a, sg):
                if sk != 0.0:
                    wi = sk + (wi - sk) * ak
                out.append(wi)
            w[i] = out
        if len(self._dahl_cache) > 64:
            self._dahl_cache.clear()
        self._dahl_cache[key] = w
        return w

    def initial_states(self, starts: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Estimated window-start states (num_states, len(starts)) for copies with
        catalog parameters ``P`` (num_params, len(starts)).

        Angles and velocities come from the smoothed measurements.  The hysteresis
        force is physics, not a reading: the Dahl law of the copy's loop width,
        transition length and initial state (``hysteresis_initial``, fitted) run on
        the smoothed elongation from the dataset start (:meth:`_dahl_history`).
        Reading it from the measured force instead would let it absorb any slow force
        error as a per-window offset (issue 12)."""
        n = self.nom.num_motors
        X0 = np.empty((self.nom.num_states, len(starts)))
        X0[self.xpos] = self.xhat[:, starts]
        # encoder calibration: the estimate is of the measured angles
        for i in range(n):
            X0[self.xpos[i]] -= P[PARAM_INDEX[f"motor_bias_{i + 1}"]]
        if self.nom.has_link and "joint_angle" in self.ds.outputs:
            scale = 1.0 + P[PARAM_INDEX["link_scale_rel"]]
            X0[0] = (X0[0] - P[PARAM_INDEX["link_bias"]]) / scale
            X0[1] = X0[1] / scale
        shape = P[[PARAM_INDEX["hysteresis_length"], PARAM_INDEX["hysteresis_initial"]]]
        width = P[PARAM_INDEX["hysteresis_width"]]
        w = np.zeros((n, len(starts)))
        on = width != 0
        for L, w0 in np.unique(shape[:, on].T, axis=0) if on.any() else []:
            sel = on & (shape[0] == L) & (shape[1] == w0)
            w[:, sel] = self._dahl_history(L, w0)[:, starts[sel]] * width[sel]
        X0[-n:] = w
        return X0

    # ------------------------------------------------------------------ simulate
    def _simulator(self, M: int, divisor: int):
        key = (M, divisor)
        if key not in self._sims:
            sys = DiscrepancyModel_[float](self.nom, M)
            sim = Simulator(sys)
            ResetIntegratorFromFlags(sim, "runge_kutta3", self.dt / divisor)
            integ = sim.get_mutable_integrator()
            integ.set_fixed_step_mode(True)
            ctx = sim.get_mutable_context()
            self._sims[key] = (sys, sim, ctx)
        return self._sims[key]

    def stiffness(self, P: np.ndarray) -> np.ndarray:
        """Largest rate [1/s] of each copy's fast local dynamics (num_params, M) -> (M,): the slopes of its
        friction laws at rest over the inertia they act on (motor (3.8) ``g1 g2 + g3`` and guide friction
        ``r^2 (C0 + mu f) / v0`` over ``B``, link friction ``F_c / v_s`` over the link inertia, added
        damping) and the Dahl relaxation ``|x'|/delta`` at the data's fastest elongation (x1.5).
        Backlash (a Newton step inside the law) counts as infinitely stiff."""
        nom, g = self.nom, (lambda n: P[PARAM_INDEX[n]])
        B = nom.motor_inertia * (1.0 + g("motor_inertia_rel"))
        r = nom.motor_pulley_radius
        lam = (np.abs(g("motor_slope") * g("motor_coulomb")) + np.abs(g("motor_viscous"))
               + np.abs(g("motor_damping_add"))
               + r * r * (np.abs(g("guide_c0")) + np.abs(g("guide_mu")) * self._force_max)
               / laws.GUIDE_VELOCITY) / B
        lam = np.maximum(lam, np.where(g("hysteresis_width") != 0, 1.5 * self._elong_rate_max
                                       / np.maximum(g("hysteresis_length"), 1e-12), 0.0))
        if nom.has_link:
            I = nom.link_inertia * (1.0 + g("link_inertia_rel"))
            lam = np.maximum(lam, (np.abs(g("joint_coulomb")) / np.maximum(g("joint_velocity"), 1e-12)
                                   + np.abs(g("link_damping_add"))) / I)
            lam = np.where(g("backlash") != 0, np.inf, lam)
        return lam

    def step_divisors(self, P: np.ndarray) -> np.ndarray:
        """Integrator steps per sample of each copy: ``settings.coarse_step_divisor`` where the copy's
        :meth:`stiffness` times that step is at most ``settings.coarse_step_stiffness``, else
        ``settings.step_divisor``. A copy's replay depends only on its own parameters (never on the
        batch it runs in), so finite differences between evaluations stay consistent."""
        s = self.settings
        coarse = min(s.coarse_step_divisor, s.step_divisor)
        ok = self.stiffness(P) * self.dt / coarse <= s.coarse_step_stiffness
        return np.where(ok, coarse, s.step_divisor)

    def simulate(self, starts: np.ndarray, P: np.ndarray, X0: np.ndarray) -> np.ndarray:
        """Simulate copies; returns the model measurements (M, L, num_measurements).

        Copies run in groups of equal integrator step (:meth:`step_divisors`), one Drake
        ``Simulator`` pass per group.

        Parameters
        ----------
        starts : (M,) int, window start sample of each copy
        P : (num_params, M) catalog parameters of each copy
        X0 : (num_states, M) initial state of each copy
        """
        batch = getattr(self._local, "batch", None)
        Ym = batch.simulate(starts, P, X0) if batch is not None else self._simulate_all([(starts, P, X0)])[0]
        if not np.all(np.isfinite(Ym)):
            c, k = np.nonzero(~np.isfinite(Ym))[:2]
            t = float(np.min(self.ds.time[starts[c] + 1 + k]))     # sample k of a copy: residual's index
            raise SimulationDivergedError(f"replay of {self.ds.name} diverged at t = {t:.6g} s in "
                                          f"{len(np.unique(c))} of {len(starts)} copies", t=t)
        return Ym

    def _simulate_all(self, requests: list) -> list:
        """Several :meth:`simulate` requests ``[(starts, P, X0), ...]`` as one engine pass (their copies side by
        side); returns their measurements in order. A copy's replay depends only on its own parameters and
        start, so each request gets exactly what it would get alone."""
        t0 = time.perf_counter()
        sizes = [len(st) for st, _, _ in requests]
        starts = np.concatenate([np.asarray(st) for st, _, _ in requests])
        P = np.concatenate([np.array(Pr, float) for _, Pr, _ in requests], axis=1)
        X0 = np.concatenate([np.asarray(X, float) for _, _, X in requests], axis=1)
        div = self.step_divisors(P)
        Ym = np.empty((len(starts), self.L, self.nom.num_measurements))
        for d in np.unique(div):
            sel = div == d
            Ym[sel] = self._simulate_group(starts[sel], P[:, sel], X0[:, sel], int(d))
        self.simulations += 1
        self.sim_time += time.perf_counter() - t0
        return np.split(Ym, np.cumsum(sizes)[:-1])

    def run_batched(self, jobs: list) -> list:
        """Run the callables ``jobs`` (e.g. one simulation fit each) side by side, their replays merged: each
        job runs in its own thread, and its :meth:`simulate` calls wait until every unfinished job has asked for
        one, then all are simulated in one pass (:meth:`_simulate_all`). The per-pass cost of the integrator
        (most of a small replay's cost) is paid once for all jobs; every job gets exactly the numbers it would
        get alone. Returns the jobs' results in order; re-raises the first job's exception."""
        if len(jobs) <= 1:
            return [job() for job in jobs]
        batch = _Batch(self, len(jobs))
        results, errors = [None] * len(jobs), [None] * len(jobs)

        def work(i):
            self._local.batch = batch
            try:
                results[i] = jobs[i]()
            except BaseException as exc:   # noqa: BLE001 - re-raised in the caller's thread
                errors[i] = exc
            finally:
                self._local.batch = None
                batch.finished()

        threads = [threading.Thread(target=work, args=(i,), daemon=True) for i in range(len(jobs))]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        for exc in errors:
            if exc is not None:
                raise exc
        return results

    def _simulate_group(self, starts: np.ndarray, P: np.ndarray, X0: np.ndarray, divisor: int) -> np.ndarray:
        M = len(starts)
        sys, sim, ctx = self._simulator(M, divisor)
        ctx.SetTime(0.0)
        ctx.SetContinuousState(np.ascontiguousarray(X0).ravel())
        # spring drift (creep): the spring scale of each copy at its window's mid-time
        t_mid = self.ds.time[starts] + 0.5 * self.L * self.dt - 0.5 * (self.ds.time[0] + self.ds.time[-1])
        P = P.copy()
        P[PARAM_INDEX["spring_scale_rel"]] += P[PARAM_INDEX["spring_drift"]] * t_mid
        ctx.get_mutable_numeric_parameter(0).SetFromVector(P.ravel())
        delay = P[PARAM_INDEX["delay"]] / self.dt
        nd = np.floor(delay).astype(int)
        a = delay - nd
        port = sys.get_input_port(0)
        out = sys.get_output_port(0)
        ny = self.nom.num_measurements
        Ym = np.empty((M, self.L, ny))
        # the delayed, interpolated commands of every sample at once: (L, n * M) in the port's order
        k = np.arange(self.L)[:, None]
        i0 = np.clip(starts[None] + k - nd[None], 0, self.N - 1)
        i1 = np.clip(starts[None] + k - nd[None] - 1, 0, self.N - 1)
        u = (1 - a)[None, :, None] * self.U[i0] + a[None, :, None] * self.U[i1]  # (L, M, n)
        u = np.ascontiguousarray(np.transpose(u, (0, 2, 1)).reshape(self.L, -1))
        sim.Initialize()
        for k in range(self.L):
            port.FixValue(ctx, u[k])
            sim.AdvanceTo((k + 1) * self.dt)
            Ym[:, k, :] = out.Eval(ctx).reshape(ny, M).T
        return Ym

    def residual(self, starts: np.ndarray, Ym: np.ndarray) -> np.ndarray:
        """Normalised residual (measured - model)/sigma, shape (M, L * ny_measured)."""
        idx = starts[:, None] + 1 + np.arange(self.L)[None, :]
        meas = self.Y[idx]  # (M, L, ny)
        pred = Ym[:, :, self.out_index]
        return ((meas - pred) / self.sigma).reshape(len(starts), -1)

    # ------------------------------------------------------------------ batches
    def evaluate(self, Psets: np.ndarray, windows: np.ndarray, state_perturbations=None) -> np.ndarray:
        """Residuals of several parameter sets on several windows in one simulation.

        Parameters
        ----------
        Psets : (S, num_params) parameter vectors
        windows : (W,) window indices
        state_perturbations : (K, num_states), optional; adds K copies per
            window of the *first* parameter set with perturbed initial states.

        Returns
        -------
        (S + K, W, L * ny) normalised residuals.
        """
        Psets = np.atleast_2d(Psets)
        S, W = len(Psets), len(windows)
        starts_w = self.starts[windows]
        K = 0 if state_perturbations is None else len(state_perturbations)
        starts = np.tile(starts_w, S + K)
        P = np.repeat(np.vstack([Psets, np.repeat(Psets[:1], K, axis=0)]).T.astype(float), W, axis=1)
        X0 = self.initial_states(starts, P)
        for k in range(K):
            X0[:, (S + k) * W:(S + k + 1) * W] += state_perturbations[k][:, None]
        Ym = self.simulate(starts, P, X0)
        return self.residual(starts, Ym).reshape(S + K, W, -1)

    def state_steps(self) -> np.ndarray:
        """Initial-state perturbations used for the profile, one row per profiled state
        (angles, velocities; not the hysteresis force, which is physics, see
        :meth:`initial_states`), in the order of :attr:`xhat`: shape (num_states - num_motors, num_states)."""
        nom = self.nom
        n = nom.num_motors
        th_scale = np.maximum(self.xhat[:n].std(axis=1), 1e-3) * 1e-2
        om_scale = np.maximum(self.xhat[n:2 * n].std(axis=1), 1e-2) * 1e-2
        steps = list(th_scale) + list(om_scale)
        if nom.has_link:
            steps += [max(self.xhat[2 * n].std(), 1e-3) * 1e-2, max(self.xhat[2 * n + 1].std(), 1e-2) * 1e-2]
        D = np.zeros((len(steps), nom.num_states))
        D[np.arange(len(steps)), self.xpos] = steps
        return D

    def state_prior_std(self) -> np.ndarray:
        """Standard deviation of the window-start state estimate (prior of the profile).

        Angles: twice the noise floor times the Savitzky-Golay noise gain; velocities:
        twice the derivative-filter noise gain plus 2 % of their RMS (smoothing bias at
        fast transients); hysteresis force: none, it is physics (the Dahl state follows
        from the elongation history and the fitted initial state), so it cannot act as a
        free per-window force offset (issue 12)."""
        n = self.nom.num_motors
        win = self._sg_window
        g0 = float(np.sqrt(np.sum(savgol_coeffs(win, 3) ** 2)))
        g1 = float(np.sqrt(np.sum(savgol_coeffs(win, 3, deriv=1, delta=self.dt) ** 2)))
        sfx = ["_1", "_2"] if n == 2 else [""]
        sig_th = np.array([self.sigma[self.out_names.index(f"motor_angle{s}")] for s in sfx])
        om_rms = np.sqrt(np.mean(self.xhat[n:2 * n] ** 2, axis=1))
        std = list(2 * g0 * sig_th) + list(2 * g1 * sig_th + 0.02 * om_rms)
        if self.nom.has_link:
            sq = noise_floor(self._q_raw)
            qd_rms = float(np.sqrt(np.mean(self.xhat[2 * n + 1] ** 2)))
            std += [max(2 * g0 * sq, 1e-9), 2 * g1 * sq + 0.02 * qd_rms]
        return np.maximum(np.array(std), 1e-12)

    def profiled(self, Psets: np.ndarray, windows: np.ndarray) -> list:
        """Residuals and window-start profiles of several parameter sets (one simulation).

        Returns a list of ``(r0, Projection)``, one per set: ``r0`` (W, L*ny) is the
        residual from the estimated window starts, the projection profiles it over
        the window initial states (sensitivities by finite differences at that set)."""
        Psets = np.atleast_2d(Psets)
        D = self.state_steps()
        prior = self.state_prior_std()
        ns = D.shape[0]
        Sn, W = len(Psets), len(windows)
        starts = np.tile(self.starts[windows], Sn * (1 + ns))
        P = np.repeat(np.repeat(Psets, 1 + ns, axis=0).T, W, axis=1)
        X0 = self.initial_states(starts, P)
        for s in range(Sn):
            for k in range(ns):
                b = (s * (1 + ns) + 1 + k) * W
                X0[:, b:b + W] += D[k][:, None]
        Ym = self.simulate(starts, P, X0)
        R = self.residual(starts, Ym).reshape(Sn, 1 + ns, W, -1)
        out = []
        for s in range(Sn):
            r0 = R[s, 0]
            S = (r0[None] - R[s, 1:]) / D.sum(axis=1)[:, None, None]  # d(pred)/dx0: (ns, W, m)
            out.append((r0, Projection(np.transpose(S, (1, 2, 0)) * prior[None, None, :])))
        return out

    def projector(self, Pbase: np.ndarray, windows: np.ndarray):
        """Base residual and the window-start profile of one parameter set.

        Returns
        -------
        r0 : (W, L*ny) base residual
        proj : :class:`Projection` (apply with :func:`project`)
        """
        return self.profiled(np.asarray(Pbase)[None], windows)[0]


class _Batch:
    """The pending :meth:`ReplayEngine.simulate` requests of the jobs of one :meth:`ReplayEngine.run_batched`:
    when every unfinished job waits on one, the last to arrive runs them all in one pass."""

    def __init__(self, eng: ReplayEngine, jobs: int):
        self.eng, self.live, self.pending = eng, jobs, []
        self.cv = threading.Condition()

    def simulate(self, starts, P, X0):
        req = {"args": (starts, P, X0)}
        with self.cv:
            self.pending.append(req)
            self._run_if_all_wait()
            while "out" not in req:
                self.cv.wait()
        if isinstance(req["out"], BaseException):
            raise req["out"]
        return req["out"]

    def finished(self):
        with self.cv:
            self.live -= 1
            self._run_if_all_wait()

    def _run_if_all_wait(self):
        if not self.pending or len(self.pending) < self.live:
            return
        reqs, self.pending = self.pending, []
        try:
            outs = self.eng._simulate_all([r["args"] for r in reqs])
        except BaseException as exc:   # noqa: BLE001 - handed to every waiting job
            outs = [exc] * len(reqs)
        for r, out in zip(reqs, outs):
            r["out"] = out
        self.cv.notify_all()


class Projection:
    """Profile over the window initial states with a Gaussian prior (per window).

    With ``S`` the prior-scaled initial-state sensitivities of a window, the
    residual energy minimised over the initial-state correction ``d`` with prior
    ``|d|^2`` is ``r^T (I + S S^T)^-1 r = |C r|^2``, ``C = (I + S S^T)^-1/2 = I - S K S^T``,
    ``K = f(S^T S)`` with ``f(l) = (1 - 1/sqrt(1 + l))/l = 1/((1 + sqrt(1 + l)) sqrt(1 + l))``
    (from ``S = U diag(s) V^T``: ``C = I - U diag(1 - 1/sqrt(1 + s^2)) U^T``).  Only the small
    Gram matrix ``S^T S`` is decomposed (batched over windows; ``f`` has no pole at
    ``l = 0``), so no per-window SVD of the tall ``S``.  :func:`project` applies ``C``,
    so least squares on projected residuals is exact generalised least squares.
    """

    def __init__(self, S: np.ndarray):
        S = np.asarray(S, float)
        lam, V = np.linalg.eigh(np.einsum("wmk,wml->wkl", S, S))
        lam = np.maximum(lam, 0.0)
        root = np.sqrt(1.0 + lam)
        self.S = S
        self.K = np.einsum("wkj,wj,wlj->wkl", V, 1.0 / ((1.0 + root) * root), V)
        self._G = np.einsum("wkj,wj,wlj->wkl", V, 1.0 / (1.0 + lam), V)   # (I + S^T S)^-1
        self.dof = S.shape[1] - np.sum(lam / (1.0 + lam), axis=1)

    def correction(self, R: np.ndarray) -> np.ndarray:
        """Prediction change of the MAP window-start correction (linearised), in residual
        units: ``S d* = S (I + S^T S)^-1 S^T r``; R is (W, m)."""
        coef = np.einsum("wkl,wl->wk", self._G, np.einsum("wmk,wm->wk", self.S, R))
        return np.einsum("wmk,wk->wm", self.S, coef)

    @staticmethod
    def merge(parts: list) -> "Projection":
        """One projection from per-window parts ``[(positions, Projection), ...]`` (positions index the
        merged windows; together they cover each exactly once)."""
        W = sum(len(pos) for pos, _ in parts)
        first = parts[0][1]
        out = Projection.__new__(Projection)
        out.S = np.empty((W,) + first.S.shape[1:])
        out.K, out._G = np.empty((W,) + first.K.shape[1:]), np.empty((W,) + first.K.shape[1:])
        out.dof = np.empty(W)
        for pos, part in parts:
            out.S[pos], out.K[pos], out._G[pos], out.dof[pos] = part.S, part.K, part._G, part.dof
        return out

    def take(self, windows: np.ndarray) -> "Projection":
        """The profile of the windows ``windows`` (positions in this projection)."""
        out = Projection.__new__(Projection)
        out.S, out.K, out._G, out.dof = self.S[windows], self.K[windows], self._G[windows], self.dof[windows]
        return out


def project(R: np.ndarray, proj: Projection) -> np.ndarray:
    """Apply the window-start profile ``C`` to residuals ``R`` of shape (..., W, m)."""
    coef = np.einsum("wkl,...wl->...wk", proj.K, np.einsum("wmk,...wm->...wk", proj.S, R))
    return R - np.einsum("wmk,...wk->...wm", proj.S, coef)


def xhat_positions(nom: NominalParameters) -> np.ndarray:
    """Model-state index (rigs' order ``[(q, q'), theta, omega, z]``) of each row of the estimate
    ``[theta, omega, (q, q')]``."""
    n, k = nom.num_motors, 2 if nom.has_link else 0
    return np.array(list(range(k, k + 2 * n)) + ([0, 1] if nom.has_link else []))


def laws_kinematics(nom: NominalParameters, xhat: np.ndarray):
    """Elongation and rate from the stacked estimate ``[theta, omega, (q, q')]``."""
    from .model import rig_kinematics
    n = nom.num_motors
    q, qd = (xhat[2 * n], xhat[2 * n + 1]) if nom.has_link else (None, None)
    return rig_kinematics(nom, xhat[:n], xhat[n:2 * n], q, qd)
