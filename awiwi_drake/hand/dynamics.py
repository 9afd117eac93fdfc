"""The finger / hand plant as one system: the links' rigid-body dynamics and the tendon drive.

:class:`HandDynamics_` is the plant of the finger and hand diagrams.  Its physics is two truths, each evaluated where it lives:

* the links: the continuous ``MultibodyPlant`` of :mod:`.plant` (mass matrix ``M(q)``, bias
  ``C(q, v) v``, gravity ``tau_g(q)``, joint damping ``d``) plus the PIP/DIP coupling element
  ``-G [q; v]`` ((5.16)-(5.17), :func:`.plant.coupling_force_gain`)::

      M(q) qdd = -P(q)^T (f + g) - G [q; v] - d v + tau_f + tau_g(q) - C(q, v) v + tau_ext

  with, when the joints' stick-slip friction is on (``LinkModel.joint_friction``), one presliding state per
  joint, its friction torque ``tau_f`` (:func:`awiwi_drake.components.friction.stick_slip_rate`);

* the tendon drive: :func:`awiwi_drake.components.fused_drive.drive_laws` (motors, springs,
  routing, hysteresis, guide friction) with ``q`` and ``qdot = v`` of the links (and the wrist
  length offsets as extra coupling "joints").

For ``AutoDiffXd`` and ``Expression`` (``Linearize``, LQR) the system evaluates the plant's own
``CalcMassMatrix`` / ``CalcBiasTerm`` / ``CalcGravityGeneralizedForces`` on a scalar-converted
copy of the plant and :func:`drive_laws`, and solves ``M qdd = rhs`` with :func:`ldl_solve` per
block of ``M`` (the fingers are independent).  For ``float`` the same function,
:func:`hand_dynamics_terms`, is traced once on ``pydrake.symbolic`` variables and compiled
(:mod:`awiwi_drake.components.codegen`) with the same :func:`ldl_solve`; a float system takes the
generic path for its first :data:`~awiwi_drake.parameters.hand.COMPILE_AFTER_CALLS` evaluations (an
operating point or a linearisation never pays the compile), or from the first call once
:meth:`HandDynamics_.kernels` has been called.  One system rather than a MultibodyPlant + drive diagram
for speed (README, "How the plants are built, and speed"); tests check it equals that diagram and its
own AutoDiffXd conversion at random states to 1e-12.  The generated source is cached on disk
(:func:`~awiwi_drake.components.codegen.kernel_cache_dir`), keyed by the drive model's content, samples
of the plant's dynamics and the package's code.

State: ``[q (n), v (n), theta (m), omega (m), z (m, hysteresis), g (m, guide friction), tau_f (n, joint friction)]``
(:func:`~awiwi_drake.rigs.base.state_names`).  Inputs ``motor_torque`` (m) [N m], ``external_torque`` (n)
[N m] and, with the wrist, ``wrist_tendon_offset`` (m) [m]; outputs ``state``, ``tendon_force`` [N],
``tendon_stiffness`` [N/m], ``elongation`` [m], ``joint_torque`` (n, the tendon part ``-P^T (f + g)``)
[N m], ``applied_torque`` (m) [N m].
"""

from __future__ import annotations

import hashlib
import inspect
import os
import pathlib
import sys
from dataclasses import dataclass, field

import numpy as np
import pydrake
import pydrake.symbolic as sym
from scipy.sparse.csgraph import connected_components
from pydrake.systems.framework import InputPortSelection, LeafSystem_, OutputPortSelection
from pydrake.systems.primitives import Linearize
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake._math import symbolic_vector
from awiwi_drake.components.codegen import code_text
from awiwi_drake.components.fused_drive import DriveModel, drive_laws
from awiwi_drake.components.motor import saturate_torque
from awiwi_drake.parameters.hand import COMPILE_AFTER_CALLS

__all__ = ["LinkModel", "ldl_solve", "hand_dynamics_terms", "build_hand_kernels", "HandDynamics_",
           "HandDynamics"]


def ldl_solve(M, b):
    """``y`` with ``M y = b`` for a symmetric positive definite ``M`` (LDL^T, no pivoting).

    Generic in the scalar type (float, AutoDiffXd, Expression object arrays); the compiled
    hand kernel runs this very source through numba.
    """
    k = b.shape[0]
    L = M.copy()
    y = b.copy()
    for j in range(k):
        for p in range(j):
            L[j, j] = L[j, j] - L[j, p] * L[j, p] * L[p, p]
        for i in range(j + 1, k):
            for p in range(j):
                L[i, j] = L[i, j] - L[i, p] * L[j, p] * L[p, p]
            L[i, j] = L[i, j] / L[j, j]
    for i in range(k):
        for p in range(i):
            y[i] = y[i] - L[i, p] * y[p]
    for i in range(k):
        y[i] = y[i] / L[i, i]
    for i in range(k - 1, -1, -1):
        for p in range(i + 1, k):
            y[i] = y[i] - L[p, i] * y[p]
    return y


@dataclass(frozen=True, eq=False)
class LinkModel:
    """The links of a finger or the hand: a finalised continuous float ``MultibodyPlant`` (standalone,
    not in a diagram) and the PIP/DIP coupling gain ``G`` (n x 2n, or None).

    ``joint_friction`` (n x 4, or None: off): per joint (position order) the stick-slip friction's Coulomb and
    breakaway levels [N m], Stribeck velocity [rad/s] and presliding angle [rad]
    (:func:`awiwi_drake.components.friction.stick_slip_rate`; one state per joint).
    Derived: ``damping`` (n) [N m s/rad] (each revolute joint's damping, position order) and
    ``blocks``, the index sets of the diagonal blocks of ``M(q)`` (one per finger).
    """

    plant: object
    coupling_gain: np.ndarray | None = None
    joint_friction: np.ndarray | None = None
    damping: np.ndarray = field(init=False)
    blocks: tuple = field(init=False)

    def __post_init__(self):
        plant = self.plant
        n = plant.num_positions()
        if plant.num_velocities() != n:
            raise ValueError(f"LinkModel: the plant has {n} positions but {plant.num_velocities()} velocities "
                             "(revolute joints only)")
        d = np.zeros(n)
        for j in plant.GetJointIndices():
            joint = plant.get_joint(j)
            if joint.num_positions() == 0:
                continue
            if joint.num_positions() != 1:
                raise ValueError(f"LinkModel: joint {joint.name()!r} has {joint.num_positions()} positions "
                                 "(revolute joints only)")
            d[joint.position_start()] = joint.default_damping_vector()[0]
        d.setflags(write=False)
        object.__setattr__(self, "damping", d)
        G = self.coupling_gain
        if G is not None:
            G = np.array(G, dtype=float)
            if G.shape != (n, 2 * n):
                raise ValueError(f"LinkModel: coupling_gain must be {n} x {2 * n}, got {G.shape}")
            G.setflags(write=False)
            object.__setattr__(self, "coupling_gain", G)
        if self.joint_friction is not None:
            jf = np.array(self.joint_friction, dtype=float)
            if jf.shape != (n, 4) or not np.all(jf[:, 2:] > 0) or not np.all(jf[:, 1] >= jf[:, 0]) or np.any(jf < 0):
                raise ValueError(f"LinkModel: joint_friction must be {n} x 4 (coulomb <= static, stribeck_velocity > 0, "
                                 f"presliding_angle > 0 per joint), got {jf.tolist()}")
            jf.setflags(write=False)
            object.__setattr__(self, "joint_friction", jf)
        # blocks of M: connected components of its sparsity at a generic configuration
        ctx = plant.CreateDefaultContext()
        plant.SetPositions(ctx, np.random.default_rng(7).uniform(-1.0, 1.0, n))
        M = plant.CalcMassMatrix(ctx)
        count, label = connected_components(np.abs(M) > 0.0, directed=False)
        blocks = tuple(tuple(int(i) for i in np.flatnonzero(label == c)) for c in range(count))
        object.__setattr__(self, "blocks", blocks)

    @property
    def num_joints(self) -> int:
        return int(self.plant.num_positions())

    @property
    def num_friction_states(self) -> int:
        """The joint friction states (one per joint when on, else 0)."""
        return 0 if self.joint_friction is None else self.num_joints

    def friction_rate(self, v, tau_f):
        """``d tau_f / dt`` of the joints' stick-slip friction (:func:`~awiwi_drake.components.friction.stick_slip_rate`)."""
        from awiwi_drake.components.friction import stick_slip_rate
        c = self.joint_friction
        return stick_slip_rate(tau_f, v, c[:, 0], c[:, 1], c[:, 2], c[:, 3])

    def fingerprint(self) -> str:
        """Digest of the plant's dynamics (M, bias, gravity at fixed sample states), G and d."""
        plant, n = self.plant, self.num_joints
        ctx = plant.CreateDefaultContext()
        rng = np.random.default_rng(11)
        h = hashlib.sha1()
        for _ in range(3):
            plant.SetPositionsAndVelocities(ctx, rng.uniform(-1.0, 1.0, 2 * n))
            for a in (plant.CalcMassMatrix(ctx), plant.CalcBiasTerm(ctx), plant.CalcGravityGeneralizedForces(ctx)):
                h.update(np.ascontiguousarray(a, dtype=float).tobytes())
        h.update(self.damping.tobytes())
        h.update(b"none" if self.coupling_gain is None else self.coupling_gain.tobytes())
        h.update(b"no joint friction" if self.joint_friction is None else self.joint_friction.tobytes())
        return h.hexdigest()


def _split(model: DriveModel, links: LinkModel, x, off):
    """``(q, v, drive states, q with the wrist offsets, joint friction torques)`` of the state ``x``."""
    n = links.num_joints
    end = 2 * n + model.num_states
    q, v, xd, tau_f = x[:n], x[n:2 * n], x[2 * n:end], x[end:]
    q_all = q if model.num_joints == n else np.concatenate([q, off])
    return q, v, xd, q_all, tau_f


def hand_dynamics_terms(model: DriveModel, links: LinkModel, plant, context, x, u, tau_ext, off):
    """``(M, rhs, drive_derivatives)`` at the state ``x`` (module docstring), generic in the scalar type.

    ``plant``/``context``: ``links.plant`` converted to the scalar type of ``x`` and a context of it.
    ``M qdd = rhs`` gives the joint accelerations; ``drive_derivatives`` are the drive's state rates.
    """
    n = links.num_joints
    q, v, xd, q_all, tau_f = _split(model, links, x, off)
    d = drive_laws(model, xd, u, q_all, v, want=("derivatives", "generalized_force"))
    plant.SetPositionsAndVelocities(context, np.concatenate([q, v]))
    M = plant.CalcMassMatrix(context)
    tau = d["generalized_force"][:n] + tau_ext - links.damping * v
    if links.coupling_gain is not None:
        tau = tau - links.coupling_gain @ np.concatenate([q, v])
    rates = d["derivatives"]
    if links.joint_friction is not None:
        tau = tau + tau_f
        rates = np.concatenate([rates, links.friction_rate(v, tau_f)])
    rhs = tau + plant.CalcGravityGeneralizedForces(context) - plant.CalcBiasTerm(context)
    return M, rhs, rates


def hand_dynamics(model: DriveModel, links: LinkModel, plant, context, x, u, tau_ext, off):
    """The state derivative ``[v, qdd, drive rates]`` (generic; :func:`ldl_solve` per block of ``M``)."""
    n = links.num_joints
    M, rhs, dd = hand_dynamics_terms(model, links, plant, context, x, u, tau_ext, off)
    qdd = np.empty(n, dtype=rhs.dtype)
    for blk in links.blocks:
        ix = np.array(blk)
        qdd[ix] = ldl_solve(np.asarray(M)[np.ix_(ix, ix)], rhs[ix])
    return np.concatenate([x[n:2 * n], qdd, dd])


# --- compiled float path --------------------------------------------------------------------------
_KERNELS: dict = {}
_SOURCE_DIGEST: list = []


def _package_digest() -> str:
    """Digest of the package code the trace depends on (laws, hand, codegen; each file as
    :func:`~awiwi_drake.components.codegen.code_text`, so docstring and comment edits keep the cached kernels) and of
    Drake's version."""
    if not _SOURCE_DIGEST:
        root = pathlib.Path(__file__).resolve().parents[1]
        h = hashlib.sha1(str(getattr(pydrake, "__version__", "")).encode())
        paths = [p for folder in ("components", "hand", "parameters") for p in sorted((root / folder).glob("*.py"))]
        for path in paths + [root / "_math.py"]:
            h.update(path.name.encode() + b"\0")
            h.update(code_text(path.read_text()).encode() + b"\0")
        _SOURCE_DIGEST.append(h.hexdigest())
    return _SOURCE_DIGEST[0]


def _glue_source(n: int, kd: int, blocks) -> str:
    """numba source of ``dynamics(x, u, tau_ext, off, out)``: the generated terms, then ``ldl_solve`` per block."""
    lines = ["@numba.njit(cache=True, error_model='numpy')"] + inspect.getsource(ldl_solve).splitlines()
    lines += ["", "", "@numba.njit(cache=True, error_model='numpy')",
              "def dynamics(a0, a1, a2, a3, out):",
              f"    t = terms(a0, a1, a2, a3, np.empty({kd + n}))",
              f"    out[0:{n}] = a0[{n}:{2 * n}]",
              f"    out[{2 * n}:] = t[0:{kd}]"]
    for b, blk in enumerate(blocks):
        k = len(blk)
        lines.append(f"    M{b} = mass{b}(a0, np.empty({k * k})).reshape(({k}, {k}))")
        lines.append(f"    r{b} = np.empty({k})")
        for j, i in enumerate(blk):
            lines.append(f"    r{b}[{j}] = t[{kd + i}]")
        lines.append(f"    y{b} = ldl_solve(M{b}, r{b})")
        for j, i in enumerate(blk):
            lines.append(f"    out[{n + i}] = y{b}[{j}]")
    lines.append("    return out")
    return "\n".join(lines) + "\n"


def build_hand_kernels(model: DriveModel, links: LinkModel, *, jit: bool = True):
    """Compiled float kernels of :func:`hand_dynamics` and the drive's outputs.

    Returns ``{name: fn}``: ``dynamics(x, u, tau_ext, off, out)`` (the state derivative),
    ``tendon_force``, ``tendon_stiffness``, ``elongation``, ``joint_torque`` ``(x, off, out)``
    (``off``: the wrist length offsets, empty without the wrist).
    """
    from awiwi_drake.components.codegen import compile_source, kernel_cache_dir
    model.require_symbolic("compiled hand dynamics",
                           "use their calibration polynomial (e.g. LeverSpringMechanism.to_polynomial())")
    ckey = getattr(model, "_content_key", None)
    key = None if ckey is None else hashlib.sha1(
        f"{ckey}|{links.fingerprint()}|{_package_digest()}".encode()).hexdigest()[:20]
    if key is not None and (key, jit) in _KERNELS:
        return _KERNELS[(key, jit)]
    names = ["dynamics", "tendon_force", "tendon_stiffness", "elongation", "joint_torque"]
    tag = f"hand_m{model.num_tendons}_n{links.num_joints}"
    source = None
    cache = kernel_cache_dir() / f"awiwi_source_{tag}_{key}.py" if key is not None else None
    if cache is not None and cache.exists():
        source = cache.read_text()
    if source is None:
        with np.errstate(invalid="ignore"):
            source = _trace_source(model, links)
        if cache is not None:
            try:
                cache.parent.mkdir(parents=True, exist_ok=True)
                tmp = cache.with_suffix(f".{os.getpid()}.tmp")    # one per process: concurrent writers never
                tmp.write_text(source)                              # share a half-written file
                tmp.replace(cache)
            except OSError:
                pass
    kernels = compile_source(source, names, tag=tag, jit=jit)
    if key is not None:
        _KERNELS[(key, jit)] = kernels
    return kernels


def _trace_source(model: DriveModel, links: LinkModel) -> str:
    from awiwi_drake.components.codegen import emit_source
    n, m = links.num_joints, model.num_tendons
    no = model.num_joints - n
    xs, x = symbolic_vector("x", 2 * n + model.num_states + links.num_friction_states)
    us, u = symbolic_vector("u", m)
    es, e = symbolic_vector("e", n)
    os_, off = symbolic_vector("o", no)
    plant = links.plant.ToSymbolic()
    context = plant.CreateDefaultContext()
    M, rhs, dd = hand_dynamics_terms(model, links, plant, context, x, u, e, off)
    kd = len(dd)
    functions = {"terms": ([xs, us, es, os_], list(dd) + list(rhs))}
    for b, blk in enumerate(links.blocks):
        functions[f"mass{b}"] = ([xs], [M[i, j] for i in blk for j in blk])
    q, v, xd, q_all, _ = _split(model, links, x, off)
    out = drive_laws(model, xd, None, q_all, v, want=("tendon_stiffness", "generalized_force"))
    for name in ("tendon_force", "tendon_stiffness", "elongation"):
        functions[name] = ([xs, os_], list(out[name]))
    functions["joint_torque"] = ([xs, os_], list(out["generalized_force"][:n]))
    return emit_source(functions, _glue_source(n, kd, links.blocks))


@TemplateSystem.define("HandDynamics_", scope=sys.modules[__name__])
def HandDynamics_(T):
    """The finger / hand plant in one system (see the module docstring); ``HandDynamics_[T](model, links)``."""

    class Impl(LeafSystem_[T]):
        def _construct(self, model: DriveModel = None, links: LinkModel = None, converter=None):
            LeafSystem_[T].__init__(self, converter)
            if not isinstance(model, DriveModel) or not isinstance(links, LinkModel):
                raise ValueError("HandDynamics: give a DriveModel and a LinkModel")
            n, m = links.num_joints, model.num_tendons
            if model.has_link:
                raise ValueError("HandDynamics: the drive model must not carry links (link_inertia)")
            if model.num_joints not in (n, n + m) or model.rate_joints != n:
                raise ValueError(f"HandDynamics: the drive's coupling has {model.num_joints} joints "
                                 f"({model.rate_joints} with velocity); the plant has {n} (plus {m} wrist offsets)")
            if T is sym.Expression and not model.supports_symbolic:
                raise ValueError("HandDynamics: a spring law of this drive cannot be evaluated symbolically")
            self.model, self.links = model, links
            self._n, self._m = n, m
            self._wrist = model.num_joints == n + m
            self._float = T is float
            self._kernels = None
            self._generic_calls = 0           # float evaluations by the generic path so far
            self._plant_T = None
            kd = model.num_states + links.num_friction_states
            self._size = 2 * n + kd
            self._buf = np.empty(self._size)
            self._empty = np.zeros(0)
            xc = self.DeclareContinuousState(n, n, kd)
            self._u = self.DeclareVectorInputPort("motor_torque", m)
            self._ext = self.DeclareVectorInputPort("external_torque", n)
            self._off = self.DeclareVectorInputPort("wrist_tendon_offset", m) if self._wrist else None
            state = self.all_state_ticket()
            self.DeclareStateOutputPort("state", xc)      # copied in C++; the diagram slices it (Demultiplexer)
            deps = {state} | ({self._off.ticket()} if self._off is not None else set())
            for name, size in (("tendon_force", m), ("tendon_stiffness", m), ("elongation", m),
                               ("joint_torque", n)):
                self.DeclareVectorOutputPort(name, size, self._law_output(name), prerequisites_of_calc=set(deps))
            self.DeclareVectorOutputPort("applied_torque", m, self._calc_applied,
                                         prerequisites_of_calc={self._u.ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.model, other.links, converter=converter)

        def kernels(self):
            """The compiled float kernels (generated on first use)."""
            if self._kernels is None:
                self._kernels = build_hand_kernels(self.model, self.links)
                self._bufs = {"tendon_force": np.empty(self._m), "tendon_stiffness": np.empty(self._m),
                              "elongation": np.empty(self._m), "joint_torque": np.empty(self._n)}
            return self._kernels

        def _plant(self):
            """The links' plant in this system's scalar type and a context of it (the generic path)."""
            if self._plant_T is None:
                plant = self.links.plant if self._float else self.links.plant.ToScalarType[T]()
                self._plant_T = (plant, plant.CreateDefaultContext())
            return self._plant_T

        def _compiled(self):
            """Whether this float evaluation takes the compiled kernels (else the generic path, counted)."""
            if self._kernels is not None:
                return True
            if self._generic_calls < COMPILE_AFTER_CALLS:
                self._generic_calls += 1
                return False
            self.kernels()
            return True

        def _offsets(self, context):
            if self._off is None:
                return self._empty if self._float else np.zeros(0, dtype=object)
            return self._off.Eval(context)

        def _law_output(self, name):
            n = self._n
            if self._float:
                bound = []

                def calc_float(context, out):
                    if not bound:
                        if not self._compiled():
                            return calc(context, out)
                        bound.extend((self.kernels()[name], self._bufs[name]))
                    fn, buf = bound
                    out.SetFromVector(fn(context.get_continuous_state_vector().CopyToVector(),
                                         self._offsets(context), buf))

            def calc(context, out):
                x = context.get_continuous_state_vector().CopyToVector()
                q, v, xd, q_all, _ = _split(self.model, self.links, x, self._offsets(context))
                key = "generalized_force" if name == "joint_torque" else name
                res = drive_laws(self.model, xd, None, q_all, v, want=(key,))[key]
                out.SetFromVector(res[:n] if name == "joint_torque" else res)
            return calc_float if self._float else calc

        def _calc_applied(self, context, out):
            out.SetFromVector(saturate_torque(self._u.Eval(context), self.model.motor))

        def integration_modes(self, context) -> np.ndarray:
            """Eigenvalues [1/s] of this plant's dynamics linearised at ``context``'s state with its inputs held at
            their values there: the modes a fixed-step integrator meets between two samples of a loop
            (:func:`~awiwi_drake.analysis.simulate` calls this hook on any leaf that has it; the state need not be an
            equilibrium).  The Jacobian is central differences of the compiled float dynamics (steps
            ``1e-6 max(1, |x_j|)``, one state of every finger at once, :meth:`_finger_states`; equal to Drake's
            ``Linearize`` to 1e-6, tests/test_simulate_stability.py), or Drake's ``Linearize`` when the drive has no
            compiled kernels.  The eigenvalues are those of the Jacobian's strongly connected blocks."""
            if not self._float:
                raise ValueError("HandDynamics.integration_modes: float systems only")
            x0 = context.get_continuous_state_vector().CopyToVector()
            u, ext, off = self._u.Eval(context), self._ext.Eval(context), self._offsets(context)
            if self.model.supports_symbolic:
                fn = self.kernels()["dynamics"]
                A = np.zeros((x0.size, x0.size))
                groups = self._finger_states()
                for c in range(max(len(g) for g in groups)):    # column c of every finger at once
                    cols = np.array([g[c] for g in groups if c < len(g)])
                    d = 1e-6 * np.maximum(1.0, np.abs(x0[cols]))
                    x = x0.copy()
                    x[cols] += d
                    plus = fn(x, u, ext, off, self._buf).copy()
                    x[cols] = x0[cols] - d
                    diff = plus - fn(x, u, ext, off, self._buf)
                    for g in groups:
                        if c < len(g):
                            A[g, g[c]] = diff[g] / (2 * d[cols == g[c]][0])
            else:
                ctx = self.CreateDefaultContext()
                ctx.SetStateAndParametersFrom(context)
                for port, value in ((self._u, u), (self._ext, ext), (self._off, off)):
                    if port is not None:
                        port.FixValue(ctx, value)
                A = Linearize(self, ctx, InputPortSelection.kNoInput, OutputPortSelection.kNoOutput,
                              equilibrium_check_tolerance=np.inf).A()
            n, label = connected_components(A != 0, directed=True, connection="strong")
            return np.concatenate([np.linalg.eigvals(A[np.ix_(label == k, label == k)]) for k in range(n)])

        def _finger_states(self) -> list:
            """The state indices of each finger (its joints' and its tendons' states): the fingers' dynamics are
            independent, so one evaluation perturbs one state of every finger.  One group for a finger."""
            coupling, n, m = self.model.coupling, self._n, self._m
            slices = getattr(coupling, "joint_slices", None)
            if not slices:
                return [np.arange(self._size)]
            per_tendon = self.model.num_states // m
            friction = self.links.num_friction_states
            groups = []
            for name, js in slices.items():
                joints = np.arange(n)[js]
                tendons = np.arange(m)[coupling.tendon_slices[name]]
                groups.append(np.concatenate([joints, n + joints]
                                             + [2 * n + r * m + tendons for r in range(per_tendon)]
                                             + ([2 * n + self.model.num_states + joints] if friction else [])))
            every = np.sort(np.concatenate(groups))
            return groups if np.array_equal(every, np.arange(self._size)) else [np.arange(self._size)]

        def DoCalcTimeDerivatives(self, context, derivatives):
            if self._float and self._compiled():     # the simulation hot path: one compiled call
                fn = self._kernels["dynamics"]
                off = self._off.Eval(context) if self._off is not None else self._empty
                derivatives.SetFromVector(fn(context.get_continuous_state_vector().CopyToVector(),
                                             self._u.Eval(context), self._ext.Eval(context), off, self._buf))
                return
            plant, pctx = self._plant()
            x = context.get_continuous_state_vector().CopyToVector()
            derivatives.SetFromVector(hand_dynamics(self.model, self.links, plant, pctx, x, self._u.Eval(context),
                                                    self._ext.Eval(context), self._offsets(context)))

    return Impl


HandDynamics = HandDynamics_[None]
