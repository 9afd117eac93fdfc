"""Tendon routing of the fingers and the wrist: lengths ``h(q)``, coupling ``P(q)``, stiffness map.

Sign convention (docs/ARCHITECTURE.md): ``h_i(q)`` is the length of tendon path ``i``; ``P(q) = dh/dq``
(m x n); spring elongation ``x = r_m theta + h(q) - h(0) + x0``; joint torque ``tau = -P(q)^T f``.
The lengths are the single truth and ``P`` is derived from them; where the thesis prints other rows
((5.9), (5.18), (5.21)) docs/REPRODUCTIONS.md reports both readings.

* Index / middle, (5.5): the eight lengths as printed.
* Ring / fifth, (5.16)-(5.18): the plant keeps PIP and DIP as two joints (the coupling is a stiff
  element, :mod:`.plant`); the six ring tendons are the four base rows of (5.5) and one PIP/DIP pair
  ``h = +-(r42 q42 + r43 q43)`` (reduced 3-DoF row ``+-(r42 + r43^2/r42) q42``,
  :func:`reduced_coupling_matrix`).
* Fifth: no equations in the thesis.  Chosen: the ring routing plus an antagonistic pair on the
  hematometacarpal (HMC) joint, ``h = +-r_h q_5h`` (rows 1-2): 8 tendons, 4 DoF (section 5.5).
* Thumb, (5.20)-(5.22): the four base tendons run straight from the palm points A0..D0 (frame 10) to
  the bone points A..D (frame 12), ``h_i = |T^12_10(q10, q11) p_i - p0_i|``; the PIP/DIP rows are (5.22).
  ``P`` and the tension Hessian ``sum_i f_i d^2 h_i/dq^2`` are analytic.

Stiffness (5.12) under our convention: ``K_q = -d tau/dq = P^T K_t P + sum_i f_i d^2 h_i / dq^2``
(:func:`joint_stiffness`).
"""

from __future__ import annotations

import abc
from typing import Sequence

import numpy as np
from scipy.linalg import block_diag

from .._math import is_float
from ..components.tendon import joint_stiffness as tendon_joint_stiffness
from ..parameters.hand import (FINGERS, TENDON_SLICES, FingerParams, HandParams, ThumbParams,
                               check_finger_structure, finger_params)
from .kinematics import finger_joint_names, rot_y, rot_z

__all__ = ["FingerCoupling", "LinearFingerCoupling", "ThumbCoupling", "HandCoupling",
           "finger_coupling", "hand_coupling", "joint_stiffness", "reduced_coupling_matrix",
           "dof_selection", "index_coupling_matrix"]


def _quiet_fp(method):
    """numpy reports stale floating-point flags (set inside pydrake.symbolic) as
    'invalid value' warnings on object arrays; they carry no information here."""
    def wrapper(self, q, *args, **kw):
        if isinstance(q, np.ndarray) and q.dtype != object:
            return method(self, q, *args, **kw)
        with np.errstate(invalid="ignore"):
            return method(self, q, *args, **kw)
    wrapper.__name__, wrapper.__doc__ = method.__name__, method.__doc__
    return wrapper


class FingerCoupling(abc.ABC):
    """Base of the coupling objects: ``h(q)``, ``P(q)``, ``tension_hessian(q, f)``.

    Attributes ``num_tendons`` (m), ``num_joints`` (n), ``tendon_names``, ``joint_names``, ``finger``;
    ``is_constant`` when ``P`` does not depend on ``q``; ``parts``, ``joint_slices``, ``tendon_slices`` map each
    finger the routing spans to its coupling, joints and tendons.  Methods are generic in the scalar type.
    """

    num_tendons: int
    num_joints: int
    tendon_names: list[str]
    joint_names: list[str]
    is_constant: bool = True
    finger: str = "finger"

    @property
    def parts(self) -> dict:
        return {self.finger: self}

    @property
    def joint_slices(self) -> dict:
        return {self.finger: slice(0, self.num_joints)}

    @property
    def tendon_slices(self) -> dict:
        return {self.finger: slice(0, self.num_tendons)}

    def _check_q(self, q):
        q = np.asarray(q) if is_float(np.asarray(q)) else np.asarray(q, dtype=object)
        if q.shape != (self.num_joints,):
            raise ValueError(f"{type(self).__name__}: q must have shape ({self.num_joints},) "
                             f"(joints {', '.join(self.joint_names)}), got {q.shape}")
        return q

    @abc.abstractmethod
    def h(self, q) -> np.ndarray:
        """Tendon path lengths h(q) (m,) [m]."""

    @abc.abstractmethod
    def P(self, q) -> np.ndarray:
        """Coupling matrix dh/dq (m x n) [m/rad]."""

    def tension_hessian(self, q, f) -> np.ndarray:
        """``sum_i f_i d^2 h_i/dq^2 = d(P(q)^T f)/dq`` at fixed ``f`` (n x n): the ``dP^T/dq f`` term of (5.12)."""
        return np.zeros((self.num_joints, self.num_joints))

    def tension_hessians(self, q) -> np.ndarray:
        """``d^2 h_i/dq^2`` of every tendon (m x n x n): ``tension_hessian(q, f) = sum_i f_i [i]``."""
        return np.stack([self.tension_hessian(q, e) for e in np.eye(self.num_tendons)], axis=0)


class LinearFingerCoupling(FingerCoupling):
    """Constant coupling: ``h(q) = P q`` (index, middle, ring, fifth)."""

    def __init__(self, P: np.ndarray, *, joint_names: Sequence[str], tendon_names: Sequence[str],
                 dof_selection: np.ndarray | None = None, finger: str = "finger"):
        P = np.asarray(P, dtype=float)
        if P.shape != (len(tendon_names), len(joint_names)):
            raise ValueError(f"P has shape {P.shape}, expected ({len(tendon_names)}, {len(joint_names)})")
        self._P, self.finger = P, finger
        self.num_tendons, self.num_joints = P.shape
        self.joint_names = list(joint_names)
        self.tendon_names = list(tendon_names)
        # plant joints = S @ independent DoF (identity for uncoupled fingers)
        self.dof_selection = np.eye(self.num_joints) if dof_selection is None else np.asarray(dof_selection)

    @_quiet_fp
    def h(self, q):
        return self._P @ self._check_q(q)

    def P(self, q=None):
        if q is not None:
            self._check_q(q)
        return self._P.copy()

    def dof_pseudo_inverse(self) -> np.ndarray:
        """``(P S)^+`` (n_dof x m): the least-squares inverse of (5.15) on the independent DoF (computed once)."""
        if getattr(self, "_dof_pinv", None) is None:
            self._dof_pinv = np.linalg.pinv(reduced_coupling_matrix(self))
        return self._dof_pinv


def index_coupling_matrix(r0: float, r1: float, r2: float, r3: float) -> np.ndarray:
    """``P = dh/dq`` of (5.5) (8 x 4; joints abd, MCP, PIP, DIP)."""
    return np.array([
        [r0, r1, 0, 0], [r0, -r1, 0, 0], [-r0, r1, 0, 0], [-r0, -r1, 0, 0],
        [0, 0, r2, 0], [0, 0, -r2, 0], [0, 0, r2, -r3], [0, 0, -r2, r3]], dtype=float)


def reduced_coupling_matrix(coupling: LinearFingerCoupling) -> np.ndarray:
    """Coupling matrix on the independent DoF, ``P S`` (ring: the 6 x 3 ``P4`` of section 5.3.3)."""
    return coupling.P() @ coupling.dof_selection


def _linear_finger(finger: str, p: FingerParams) -> LinearFingerCoupling:
    """The routing of a serial finger (module docstring) and its ``S`` (``q_plant = S q_dof``: for coupled fingers
    DIP = (r_x3/r_x2) PIP, (5.16))."""
    r0, r1, r2, r3 = p.abduction_radius, p.mcp_radius, p.pip_radius, p.dip_radius
    P = index_coupling_matrix(r0, r1, r2, r3)
    S = np.eye(4 + int(p.has_hmc), 4 + int(p.has_hmc) - int(p.pip_dip_coupled))
    if p.pip_dip_coupled:
        P = np.vstack([P[:4], [[0, 0, r2, r3], [0, 0, -r2, -r3]]])
        S[-1, -1] = p.dip_pip_ratio
    if p.has_hmc:
        rh = p.hmc_radius
        P = np.vstack([np.hstack([[[rh], [-rh]], np.zeros((2, 4))]), np.hstack([np.zeros((len(P), 1)), P])])
    names = [f"{finger}_h{k + 1}" for k in range(P.shape[0])]
    return LinearFingerCoupling(P, joint_names=finger_joint_names(finger), tendon_names=names,
                                dof_selection=S, finger=finger)


_KZ = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 0]])  # dRz/dq = Rz Kz
_KY = np.array([[0.0, 0, 1], [0, 0, 0], [-1, 0, 0]])  # dRy/dq = Ry Ky


_THUMB_BASE_KERNELS: dict = {}     # compiled base kinematics per thumb geometry (ThumbCoupling._base_kernel)


class ThumbCoupling(FingerCoupling):
    """Thumb (5.20)-(5.22): tensegrity base (nonlinear) + PIP/DIP (linear)."""

    is_constant = False
    finger = "thumb"

    def __init__(self, p: ThumbParams | None = None):
        self.params = p = p or ThumbParams()
        self.num_tendons, self.num_joints = 8, 4
        self.joint_names = finger_joint_names("thumb")
        self.tendon_names = [f"thumb_h{k + 1}" for k in range(8)]
        self.palm_points = np.reshape(p.palm_points, (4, 3))
        # bone points relative to the base rotation centre: (5.19) with T^12_10 = Rz Ry Trans(L)
        self.bone_points = np.reshape(p.bone_points, (4, 3)) + np.array([p.metacarpal_length, 0, 0])
        r12, r13 = p.pip_radius, p.dip_radius
        self._P_distal = np.array([[r12, 0], [-r12, 0], [-r12, r13], [r12, -r13]], dtype=float)
        self.dof_selection = np.eye(4)

    def _base(self, q10, q11):
        return rot_z(q10)[:3, :3], rot_y(q11)[:3, :3]

    @_quiet_fp
    def base_vectors(self, q):
        """Tendon vectors ``d_i = T^12_10 p_i - p0_i`` (4 x 3) in frame 10."""
        q = self._check_q(q)
        Rz, Ry = self._base(q[0], q[1])
        return (Rz @ Ry @ self.bone_points.T).T - self.palm_points

    def distal_pseudo_inverse(self) -> np.ndarray:
        """``P_distal^+`` (2 x 4) of the PIP/DIP rows (5.22), computed once."""
        if getattr(self, "_distal_pinv", None) is None:
            self._distal_pinv = np.linalg.pinv(self._P_distal)
        return self._distal_pinv

    def _base_kernel(self):
        """Float fast path: ``(q10, q11) -> [h_0..3 (4), dh/d(q10, q11) (4 x 2), the base block of d^2 h_0..3/dq^2
        (4 x 2 x 2)]`` (Algorithm 1 needs lengths and Jacobian at every trial point), one compiled kernel generated
        from :meth:`h`, :meth:`P` and :meth:`tension_hessian` (:mod:`awiwi_drake.components.codegen`: the laws
        evaluated once on symbolic variables; the base kinematics shared by all three)."""
        key = (self.palm_points.tobytes(), self.bone_points.tobytes())
        fn = _THUMB_BASE_KERNELS.get(key)
        if fn is None:
            import pydrake.symbolic as sym
            from ..components.codegen import compile_kernels
            qv = [sym.Variable("q10"), sym.Variable("q11")]
            q = np.array([sym.Expression(qv[0]), sym.Expression(qv[1]), sym.Expression(0.0), sym.Expression(0.0)])
            with np.errstate(invalid="ignore"):
                hess = [np.asarray(self.tension_hessian(q, e))[:2, :2].ravel() for e in np.eye(8)[:4]]
                outs = list(self.h(q)[:4]) + list(np.asarray(self.P(q))[:4, :2].ravel()) + list(np.concatenate(hess))
            fn = _THUMB_BASE_KERNELS[key] = compile_kernels({"thumb_base": ([qv], outs)}, tag="thumb_base")["thumb_base"]
        return fn

    @_quiet_fp
    def h(self, q):
        q = self._check_q(q)
        if q.dtype != object:             # the compiled base kinematics (_base_kernel)
            out = self._base_kernel()(np.asarray(q[:2], dtype=float), np.empty(28))
            return np.concatenate([out[:4], self._P_distal @ q[2:]])
        d = self.base_vectors(q)
        base = np.sqrt(np.sum(d * d, axis=1))
        distal = self._P_distal @ q[2:]
        return np.concatenate([base, distal])

    def _base_jacobians(self, q):
        Rz, Ry = self._base(q[0], q[1])
        b = self.bone_points.T  # 3 x 4
        dA0 = Rz @ _KZ @ Ry @ b          # d/dq10
        dA1 = Rz @ Ry @ _KY @ b          # d/dq11
        return Rz, Ry, b, dA0, dA1

    @_quiet_fp
    def P(self, q):
        q = self._check_q(q)
        if q.dtype != object:             # the compiled base kinematics (_base_kernel)
            return self.coupling_and_hessians(q)[0]
        d = self.base_vectors(q)
        norm = np.sqrt(np.sum(d * d, axis=1))
        _, _, _, dA0, dA1 = self._base_jacobians(q)
        like = float if is_float(np.asarray(q)) else object
        P = np.zeros((8, 4), dtype=like)
        for i in range(4):
            P[i, 0] = np.dot(d[i], dA0[:, i]) / norm[i]
            P[i, 1] = np.dot(d[i], dA1[:, i]) / norm[i]
        P[4:, 2:] = self._P_distal
        return P

    def coupling_and_hessians(self, q):
        """Float fast path: ``(P(q), tension_hessians(q))`` from one call of the compiled base kinematics.

        The last base pose's result is kept (one entry, keyed by the two base angles' bytes): the sampled chain asks
        for ``P`` at one estimate several times a period (path velocity, friction observer, distribution), and this
        computes it once; copies are returned."""
        q = self._check_q(q)
        qb = np.asarray(q[:2], dtype=float)
        key = qb.tobytes()                # float64 (converted above)
        memo = self.__dict__.get("_memo")
        if memo is None or memo[0] != key:
            out = self._base_kernel()(qb, np.empty(28))
            P = np.zeros((8, 4))
            P[:4, :2] = out[4:12].reshape(4, 2)
            P[4:, 2:] = self._P_distal
            H = np.zeros((8, 4, 4))
            H[:4, :2, :2] = out[12:].reshape(4, 2, 2)
            memo = self._memo = (key, P, H)
        return memo[1].copy(), memo[2].copy()

    def tension_hessians(self, q) -> np.ndarray:
        """``d^2 h_i/dq^2`` (8 x 4 x 4); float ``q``: the compiled base kinematics (:meth:`_base_kernel`)."""
        q = self._check_q(q)
        if q.dtype == object:
            return super().tension_hessians(q)
        return self.coupling_and_hessians(q)[1]

    @_quiet_fp
    def tension_hessian(self, q, f):
        """``sum_i f_i d^2 h_i/dq^2``; only the base block (q10, q11) is non-zero."""
        q = self._check_q(q)
        d = self.base_vectors(q)
        norm = np.sqrt(np.sum(d * d, axis=1))
        Rz, Ry, b, dA0, dA1 = self._base_jacobians(q)
        d00 = Rz @ _KZ @ _KZ @ Ry @ b
        d01 = Rz @ _KZ @ Ry @ _KY @ b
        d11 = Rz @ Ry @ _KY @ _KY @ b
        like = float if (is_float(np.asarray(q)) and is_float(np.asarray(f))) else object
        H = np.zeros((4, 4), dtype=like)
        for i in range(4):
            u = d[i] / norm[i]
            J = np.stack([dA0[:, i], dA1[:, i]], axis=1)         # 3 x 2
            uJ = u @ J
            Hi = (J.T @ J - np.outer(uJ, uJ)) / norm[i]
            Hi = Hi + np.array([[u @ d00[:, i], u @ d01[:, i]], [u @ d01[:, i], u @ d11[:, i]]])
            H[:2, :2] = H[:2, :2] + f[i] * Hi
        return H


class HandCoupling(FingerCoupling):
    """Block-diagonal routing of several fingers, optionally with length-offset inputs.

    Joints: the fingers' plant joints, then ``num_offsets`` extra "joints" that add one-to-one to the
    tendon lengths (``h += d``; an identity block of P): the hand's 38 wrist offsets, so that a wrist motion
    enters the drive like any joint motion.
    """

    parts = joint_slices = tendon_slices = finger = None   # per instance (not the one-finger properties)

    def __init__(self, parts: dict[str, FingerCoupling], *, num_offsets: int = 0):
        self.parts = dict(parts)
        self.joint_slices, self.tendon_slices = {}, {}
        j = t = 0
        for name, c in self.parts.items():
            self.joint_slices[name] = slice(j, j + c.num_joints)
            self.tendon_slices[name] = slice(t, t + c.num_tendons)
            j += c.num_joints
            t += c.num_tendons
        if num_offsets not in (0, t):
            raise ValueError(f"num_offsets must be 0 or the number of tendons ({t}), got {num_offsets}")
        self.num_finger_joints = j
        self.num_offsets = num_offsets
        self.num_tendons, self.num_joints = t, j + num_offsets
        self.joint_names = [n for c in self.parts.values() for n in c.joint_names]
        self.joint_names += [f"wrist_offset_{k + 1}" for k in range(num_offsets)]
        self.tendon_names = [n for c in self.parts.values() for n in c.tendon_names]
        self.is_constant = all(c.is_constant for c in self.parts.values())

    def _float_constant_part(self):
        """Constant block matrix (all linear parts and offsets) for the float fast path."""
        if not hasattr(self, "_P_const"):
            P = np.zeros((self.num_tendons, self.num_joints))
            for n, c in self.parts.items():
                if c.is_constant:
                    P[self.tendon_slices[n], self.joint_slices[n]] = c.P(np.zeros(c.num_joints))
            if self.num_offsets:
                P[:, self.num_finger_joints:] = np.eye(self.num_tendons)
            self._P_const = P
            self._nonlinear = [n for n, c in self.parts.items() if not c.is_constant]
        return self._P_const

    @_quiet_fp
    def h(self, q):
        q = self._check_q(q)
        if q.dtype != object:   # fast path (simulation): one matmul + the nonlinear parts
            h = self._float_constant_part() @ q
            for n in self._nonlinear:
                ts = self.tendon_slices[n]
                off = q[self.num_finger_joints:][ts] if self.num_offsets else 0.0
                h[ts] = self.parts[n].h(q[self.joint_slices[n]]) + off
            return h
        h = np.concatenate([c.h(q[self.joint_slices[n]]) for n, c in self.parts.items()])
        if self.num_offsets:
            h = h + q[self.num_finger_joints:]
        return h

    @_quiet_fp
    def P(self, q):
        q = self._check_q(q)
        if q.dtype != object:           # the last pose's P kept, keyed by its bytes (as ThumbCoupling's base)
            key = (q.dtype.str, q.tobytes())
            memo = self.__dict__.get("_memo")
            if memo is None or memo[0] != key:
                P = self._float_constant_part().copy()
                for n in self._nonlinear:
                    P[self.tendon_slices[n], self.joint_slices[n]] = self.parts[n].P(q[self.joint_slices[n]])
                memo = self._memo = (key, P)
            return memo[1].copy()
        blocks = {n: c.P(q[self.joint_slices[n]]) for n, c in self.parts.items()}
        like = float if all(b.dtype != object for b in blocks.values()) else object
        P = np.zeros((self.num_tendons, self.num_joints), dtype=like)
        for n, b in blocks.items():
            P[self.tendon_slices[n], self.joint_slices[n]] = b
        if self.num_offsets:
            P[:, self.num_finger_joints:] = np.eye(self.num_tendons)
        return P

    def tension_hessian(self, q, f):
        q = self._check_q(q)
        like = float if (is_float(np.asarray(q)) and is_float(np.asarray(f))) else object
        H = np.zeros((self.num_joints, self.num_joints), dtype=like)
        for n, c in self.parts.items():
            js = self.joint_slices[n]
            H[js, js] = c.tension_hessian(q[js], np.asarray(f)[self.tendon_slices[n]])
        return H


def finger_coupling(finger: str, params=None) -> FingerCoupling:
    """Coupling object of one finger (``params`` default: the finger's defaults)."""
    p = params if params is not None else finger_params(finger)
    if finger == "thumb":
        if not isinstance(p, ThumbParams):
            raise ValueError(f"params for the thumb must be ThumbParams, got {type(p).__name__}")
        return ThumbCoupling(p)
    if finger not in FINGERS:
        raise ValueError(f"finger must be one of {FINGERS}, got {finger!r}")
    if not isinstance(p, FingerParams):
        raise ValueError(f"params for finger {finger!r} must be FingerParams, got {type(p).__name__}")
    if p.FINGER not in ("generic", finger):
        raise ValueError(f"params for finger {finger!r} are {type(p).__name__} (the {p.FINGER} finger)")
    check_finger_structure(finger, p)      # a generic FingerParams must still have this finger's structure
    return _linear_finger(finger, p)


def hand_coupling(params: HandParams | None = None, *, wrist_offsets: bool = False) -> HandCoupling:
    """All five fingers, global tendon order thumb, index, middle, ring, fifth (Table 6.2 rows 1-38)."""
    params = params or HandParams()
    c = HandCoupling({f: finger_coupling(f, params.finger(f)) for f in FINGERS},
                     num_offsets=38 if wrist_offsets else 0)
    for f in FINGERS:  # the chosen global numbering (parameters.hand.TENDON_SLICES)
        if c.tendon_slices[f] != TENDON_SLICES[f]:
            got = c.tendon_slices[f]
            raise ValueError(f"hand_coupling: the {f} finger's tendons occupy {got.start + 1}-{got.stop} of "
                             f"{c.num_tendons}, but the global tendon order (parameters.hand.TENDON_SLICES, "
                             f"Table 6.2 rows) puts them at {TENDON_SLICES[f].start + 1}-{TENDON_SLICES[f].stop}")
    return c


def dof_selection(coupling) -> np.ndarray:
    """``S`` (plant joints x independent DoF) with ``q = S q_dof`` over all fingers of a finger or hand
    coupling (block-diagonal of the fingers' ``dof_selection``; ring/fifth: the DIP follows the PIP, (5.16))."""
    return block_diag(*(np.asarray(c.dof_selection, dtype=float) for c in coupling.parts.values()))


def joint_stiffness(coupling: FingerCoupling, q, f, k_t) -> np.ndarray:
    """Joint stiffness (5.12) of ``coupling`` at ``q``: ``K_q = -d tau/dq = P^T diag(k_t) P + sum_i f_i d^2 h_i/dq^2``
    (the law: :func:`awiwi_drake.components.tendon.joint_stiffness`; the Hessian term: ``coupling.tension_hessian``).

    ``f``: the tendon forces [N] (tension positive), ``k_t``: the tendon (spring) stiffnesses [N/m]; the motors
    held fixed.
    """
    f = np.asarray(f)
    k_t = np.asarray(k_t)
    if f.shape != (coupling.num_tendons,):
        raise ValueError(f"f must have shape ({coupling.num_tendons},), got {f.shape}")
    if k_t.shape != (coupling.num_tendons,):
        raise ValueError(f"k_t must have shape ({coupling.num_tendons},), got {k_t.shape}")
    return tendon_joint_stiffness(np.asarray(coupling.P(q)), k_t, f) + coupling.tension_hessian(q, f)

