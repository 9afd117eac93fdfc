"""Wrist of the Awiwi hand (thesis ch. 6): kinematics and tendon lengths, generic in the scalar type.

The wrist's system (:class:`~awiwi_drake.hand.systems.WristTendonOffsets_`: offsets or their
motor feed-forward) is in :mod:`awiwi_drake.hand.systems`;
the Fig 6.9-6.10 study in :mod:`awiwi_drake.reproductions.ch06_wrist`.

The wrist is a *double inverted parallelogram* (crossed four-bar linkages).  The thesis (6.1)-(6.9)
gives the method but not the link lengths; this module reconstructs them from Table 6.1 (a = length,
b = width, c = thickness) by a box construction in the forearm frame 0 of Table 6.2 (x along the forearm
towards the hand, y across the width, z across the thickness, origin at a corner of the a x b x c box):

* forearm points ``B0 = (0, 0, 0)``, ``C0 = (0, 0, c)`` (the edge B0C0 is the abduction axis) and
  ``A0 = (0, b, c/2)``; palm points in the neutral wrist ``B = (a, b, c)``, ``C = (a, b, 0)``,
  ``A = (a, 0, c/2)``;
* so the links B0B and C0C are crossed space diagonals, R_BB0 = R_CC0 = sqrt(a^2 + b^2 + c^2); the palm
  edge BC equals the forearm edge B0C0, D_BC = c (side view: the flexion linkage, an inverted
  parallelogram); A is equidistant from B and C (|AB| = |AC|, (6.5)) at R_AA0 = |AM| = b from the midpoint
  M of BC; the link A0A, |AA0| = sqrt(a^2 + b^2), crosses B0..M in the top view (the abduction linkage);
* both crossing points lie on the wrist centre (a/2, b/2, c/2): the two tendon layers of Table 6.2 cross
  there in the side view, and the abduction rotates the palm about the median axis y = b/2 (Fig 6.10).

Why this construction: it is the reading of Fig 6.2-6.7 in which all four
unprinted lengths follow from a, b, c alone, both views are inverted (crossed)
parallelograms in the neutral wrist, A0 and B0C0 are apart in the top view
(Fig 6.3), the BC plane turns about B0C0 (Fig 6.4), |AB| = |AC| (6.5), and the
Table 6.2 points agree (all 38 neutral tendons ~46.6 mm long, both layers
through the flexion crossing point).  Two alternatives were rejected: the BC
plane along the wrist side makes abduction a pure translation of the palm
(contrary to Fig 6.10), and B0C0 on the median plane needs A0 on that axis
(contrary to Fig 6.3).  A consequence: the BC plane is diagonal in the top view, so flexion turns the
palm about an axis tilted by atan(b/a) = 40 deg from y and moves the tendons about half as much as
abduction, not "minimally" (docs/REPRODUCTIONS.md).

Angles
------
``q71`` (abduction) rotates the plane of the B0C0-BC linkage about the axis B0C0 (Fig 6.4); ``q73``
(flexion) is the crank angle of that linkage.  The thesis's t_B = pi/2 - q73 puts q73 = 0 at the flat,
singular linkage, so we measure ``q73`` from the neutral wrist, ``t_B = t_B0 - q73`` with
t_B0 = atan2(c, sqrt(a^2 + b^2)) = 28.9 deg (thesis q73 = ours + 61.1 deg).  Near neutral the palm turns
about twice as far as these crank angles.  At q71 = 0 the linkage assembles for q73 in about
(-56 deg, +105 deg) (at q73 = 30 deg, q71 in about (-78 deg, +178 deg)); outside the reachable set the
functions raise ``ValueError`` naming ``wrist_angle``.

Method (thesis numbering)
-------------------------
(6.1) B on its circle; (6.4) C in closed form (the non-trivial branch of
(6.2)-(6.3); the branch t_C = t_B is the parallelogram and is discarded);
(6.5)-(6.8) A on the circle of radius R_AA0 about M in the plane orthogonal
to BC, solved in closed form for t_A (a single ``atan2``; the branch is the
one through the neutral wrist); palm frame ABC: origin (A + M)/2 (centre of
the palm face), y from A to M, z from C to B, x = y x z (equal to frame 0,
translated, in the neutral wrist); (6.9) tendon lengths.

Everything is closed form (no iteration), written once for ``float``,
``AutoDiffXd`` and ``pydrake.symbolic.Expression``, so derivatives are exact.

Sign convention (docs/ARCHITECTURE.md): the spring elongation is
``x = r_m theta + h(q) - h(0) + x0``; the wrist adds ``h_wrist(q) -
h_wrist(0)`` (:func:`wrist_tendon_offsets`) to the tendon path, and the
motor angle change that cancels it is ``-offset / r_m``
(:func:`wrist_compensation`).
"""

from __future__ import annotations

import contextlib
import functools
import math
from dataclasses import dataclass

import numpy as np

from awiwi_drake._math import Tangent, is_float, scalar_value
from awiwi_drake.parameters.wrist import WristParams

__all__ = [
    "WristPose",
    "wrist_kinematics",
    "wrist_constraint_errors",
    "wrist_tendon_lengths",
    "wrist_tendon_offsets",
    "wrist_jacobian",
    "wrist_lengths_and_jacobian",
    "wrist_compensation",
    "wrist_params",
    "check_motor_pulley_radius",
    "TENDON_FINGERS",
]

#: Finger served by each tendon row of Table 6.2 (thumb 1-8, index 9-16,
#: middle 17-24, ring 25-30, fifth 31-38; see the hand module for the routing).
TENDON_FINGERS = ("thumb",) * 8 + ("index",) * 8 + ("middle",) * 8 + ("ring",) * 6 + ("fifth",) * 8


# ---------------------------------------------------------------------------
# small scalar-generic vector helpers (3-vectors as numpy arrays, float or object)
def _vec(x, y, z):
    return np.array([x, y, z], dtype=object if not (is_float(x) and is_float(y) and is_float(z)) else float)


def _cross(u, v):
    return _vec(u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])


def _norm(u):
    return np.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])


def _symbolic_errstate(*args):
    """Silence numpy's spurious 'invalid value' flags after object loops over symbolic Expressions (set
    inside Drake's constructors), for symbolic input only."""
    if any(scalar_value(a) is None for a in args):
        return np.errstate(invalid="ignore")
    return contextlib.nullcontext()


def wrist_params(params=None) -> WristParams:
    """``params`` validated (a :class:`WristParams`), or the default wrist when None."""
    if params is None:
        return _default_params()
    if not isinstance(params, WristParams):
        raise ValueError(f"params must be a WristParams, got {type(params).__name__}")
    return params


@functools.lru_cache(maxsize=1)
def _default_params() -> WristParams:
    return WristParams()


# ---------------------------------------------------------------------------
@dataclass
class WristPose:
    """Points and palm frame of the wrist at one configuration, in frame 0 [m]: palm points A, B, C, forearm
    points A0, B0, C0, the midpoint M of BC, the palm frame ABC (``rotation``: columns x, y, z; ``origin``)
    and the circle parameters t_A, t_B, t_C [rad] of (6.5) and (6.1)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    A0: np.ndarray
    B0: np.ndarray
    C0: np.ndarray
    M: np.ndarray
    rotation: np.ndarray
    origin: np.ndarray
    t_A: object
    t_B: object
    t_C: object

    def transform(self) -> np.ndarray:
        """Homogeneous transform T^0_ABC (4 x 4) of the palm frame in the forearm frame."""
        T = np.zeros((4, 4), dtype=self.rotation.dtype)
        T[:3, :3] = self.rotation
        T[:3, 3] = self.origin
        T[3, 3] = 1.0
        return T


def wrist_kinematics(q71, q73, params: WristParams | None = None) -> WristPose:
    """Solve the double inverted parallelogram, thesis (6.1)-(6.8): the :class:`WristPose` at abduction ``q71``
    and flexion ``q73`` [rad] (float, AutoDiffXd or Expression; angles as in the module docstring) with the
    geometry ``params`` (default: Table 6.1, 6.2).  For float/AutoDiff input a linkage that cannot be
    assembled raises ``ValueError`` naming ``q71``/``q73``.
    """
    p = wrist_params(params)
    with _symbolic_errstate(q71, q73):
        return _solve(q71, q73, p)


def _solve(q71, q73, p: WristParams) -> WristPose:
    for name, q in (("q71", q71), ("q73", q73)):
        v = scalar_value(q)
        if v is not None and not math.isfinite(v):
            raise ValueError(f"wrist_angle {name} = {v} rad is not finite")
    a, b, c = p.length, p.width, p.thickness
    L, d, R, dA = p.crank_length, p.coupler_length, p.palm_radius, p.link_length
    gamma0 = math.atan2(b, a)               # direction of the BC plane in the top view (neutral)
    tB0 = math.atan2(c, p.diagonal_length)  # neutral crank angle in the BC plane

    # BC plane: spanned by e_u (horizontal, rotated by q71 about B0C0) and e_v = z.
    g = gamma0 + q71
    cg, sg = np.cos(g), np.sin(g)
    e_u = _vec(cg, sg, 0.0)
    e_v = _vec(0.0, 0.0, 1.0)
    n = _vec(-sg, cg, 0.0)                  # plane normal: z axis of the frame BCM

    # (6.1) and (6.4): B and C in the plane (B0 at the origin, C0 at (0, D_BC)).
    tB = tB0 - q73
    ctB, stB = np.cos(tB), np.sin(tB)
    den = L * L + d * d - 2.0 * L * d * stB
    _check_positive(den, "linkage B0C0-BC is flat (t_B = +-pi/2)", q71, q73)
    Bu, Bv = L * ctB, L * stB
    Cu = L * (L * L - d * d) * ctB / den
    Cv = (L * L - d * d) * (L * stB - d) / den
    tC = np.arctan2(Cv - d, Cu)             # (6.3), measured about C0
    B = Bu * e_u + Bv * e_v
    C = Cu * e_u + Cv * e_v
    M = 0.5 * (B + C)

    # Frame BCM: x along MC, z the plane normal, y = z x x.
    BC = C - B
    x = BC / _norm(BC)
    y = _cross(n, x)
    A0 = np.array([0.0, b, 0.5 * c])
    r = A0 - M
    a0y, a0z = np.dot(r, y), np.dot(r, n)   # (6.6): A0 in BCM (x-coordinate: np.dot(r, x))
    a0x = np.dot(r, x)
    # (6.7): a0x^2 + (a0y - R cos tA)^2 + (a0z - R sin tA)^2 = dA^2
    #   <=> a0y cos tA + a0z sin tA = k, solved with one atan2 (neutral branch).
    k = (a0x * a0x + a0y * a0y + a0z * a0z + R * R - dA * dA) / (2.0 * R)
    rho2 = a0y * a0y + a0z * a0z
    disc = rho2 - k * k
    _check_positive(disc, "palm point A cannot reach |AA0| (6.7)", q71, q73)
    tA = np.arctan2(a0z, a0y) - np.arctan2(np.sqrt(disc), k)
    # (6.5), (6.8): A in frame 0.
    A = M + R * np.cos(tA) * y + R * np.sin(tA) * n

    # Palm frame ABC.
    AM = M - A
    yp = AM / _norm(AM)
    zp = -BC / _norm(BC)
    xp = _cross(yp, zp)
    rot = np.column_stack([xp, yp, zp])
    origin = 0.5 * (A + M)
    B0 = np.zeros(3)
    C0 = np.array([0.0, 0.0, c])
    return WristPose(A=A, B=B, C=C, A0=A0, B0=B0, C0=C0, M=M, rotation=rot, origin=origin,
                     t_A=tA, t_B=tB, t_C=tC)


def _check_positive(value, what: str, q71, q73) -> None:
    v = scalar_value(value)
    if v is not None and not (v > 0.0):
        raise ValueError(f"wrist_angle [q71, q73] = [{scalar_value(q71)}, {scalar_value(q73)}] rad is outside "
                         f"the reachable range of the wrist: {what}")


def wrist_constraint_errors(pose: WristPose, params: WristParams | None = None) -> np.ndarray:
    """Errors of the six distance constraints of Fig 6.9 [m]: ``[|AA0|, |BB0|, |CC0|, |AB|, |AC|, |BC|]`` minus
    their design values (``link_length``, ``crank_length`` twice, ``palm_edge_length`` twice,
    ``coupler_length``)."""
    p = wrist_params(params)
    P = pose
    d = [_norm(P.A - P.A0) - p.link_length,
         _norm(P.B - P.B0) - p.crank_length,
         _norm(P.C - P.C0) - p.crank_length,
         _norm(P.A - P.B) - p.palm_edge_length,
         _norm(P.A - P.C) - p.palm_edge_length,
         _norm(P.B - P.C) - p.coupler_length]
    return np.array(d, dtype=object if any(not is_float(e) for e in d) else float)


def wrist_tendon_lengths(q71, q73, params: WristParams | None = None) -> np.ndarray:
    """Length [m] of each tendon through the wrist, thesis (6.9): ``h_i = || h0_forearm,i - T^0_ABC h^ABC_palm,i ||``
    for the rows of Table 6.2, in table order, at the wrist angles of :func:`wrist_kinematics`."""
    p = wrist_params(params)
    pose = wrist_kinematics(q71, q73, p)
    with _symbolic_errstate(q71, q73):
        palm_in_0 = pose.origin + p.palm_offset_array @ pose.rotation.T
        diff = p.forearm_offset_array - palm_in_0
        return np.sqrt(np.sum(diff * diff, axis=1))


@functools.lru_cache(maxsize=16)
def _neutral_lengths(params: WristParams) -> np.ndarray:
    out = wrist_tendon_lengths(0.0, 0.0, params)
    out.setflags(write=False)
    return out


def wrist_tendon_offsets(q71, q73, params: WristParams | None = None) -> np.ndarray:
    """Wrist-induced tendon path change ``h_wrist(q) - h_wrist(0)`` [m], Table 6.2 order.

    Positive: the path through the wrist gets longer, which (ARCHITECTURE.md) stretches the tendon's
    spring like winding its motor would.  Generic in the scalar type.

    Examples
    --------
    >>> import numpy as np
    >>> off = wrist_tendon_offsets(np.radians(20.0), 0.0)   # 20 deg abduction
    >>> off.shape
    (38,)
    """
    p = wrist_params(params)
    return wrist_tendon_lengths(q71, q73, p) - _neutral_lengths(p)


def wrist_lengths_and_jacobian(q71, q73, params: WristParams | None = None):
    """``(h, P)``: the tendon lengths (6.9) [m] and their exact Jacobian ``dh/d[q71, q73]`` [m/rad] (the wrist
    block of the coupling matrix), generic in the scalar type.

    The palm pose is differentiated in forward mode (:class:`~awiwi_drake._math.Tangent`) through the
    closed-form kinematics; the tendon part uses ``dh_i/dq = -u_i . (dO/dq + dR/dq p_i)`` with ``u_i`` the
    unit vector from the palm point to the forearm point.
    """
    p = wrist_params(params)
    scalar = is_float(q71) and is_float(q73)
    unit = (np.array([1.0, 0.0]), np.array([0.0, 1.0]))
    pose = wrist_kinematics(Tangent(q71, unit[0]), Tangent(q73, unit[1]), p)
    dtype = float if scalar else object
    O = np.array([e.v for e in pose.origin], dtype=dtype)
    dO = np.array([e.d for e in pose.origin], dtype=dtype)                      # (3, 2)
    R = np.array([[e.v for e in row] for row in pose.rotation], dtype=dtype)
    dR = np.array([[e.d for e in row] for row in pose.rotation], dtype=dtype)  # (3, 3, 2)
    with _symbolic_errstate(q71, q73):
        Pp = p.palm_offset_array
        diff = p.forearm_offset_array - (O + Pp @ R.T)
        h = np.sqrt(np.sum(diff * diff, axis=1))
        u = diff / h[:, None]
        J = np.column_stack([-np.sum(u * (dO[:, j] + Pp @ dR[:, :, j].T), axis=1) for j in range(2)])
    return h, J


def wrist_jacobian(q71, q73, params: WristParams | None = None) -> np.ndarray:
    """Exact Jacobian ``d h_wrist / d [q71, q73]`` (num_tendons x 2) [m/rad].

    Row i, column j: change of tendon i's path through the wrist per radian of
    q71 (j = 0) or q73 (j = 1); the wrist block of ``P(q) = dh/dq``.  Generic
    in the scalar type (see :func:`wrist_lengths_and_jacobian`).
    """
    return wrist_lengths_and_jacobian(q71, q73, params)[1]


def wrist_compensation(q71, q73, motor_pulley_radius, params: WristParams | None = None) -> np.ndarray:
    """Motor angle change that cancels the wrist offset: ``-offset / r_m`` [rad] (``motor_pulley_radius`` r_m [m],
    a number or one per tendon)."""
    r = check_motor_pulley_radius(motor_pulley_radius, wrist_params(params).num_tendons)
    return -wrist_tendon_offsets(q71, q73, params) / r


def check_motor_pulley_radius(r, n: int) -> np.ndarray:
    """``r`` as ``n`` finite positive radii [m] (a scalar is broadcast); ValueError naming ``motor_pulley_radius``."""
    arr = np.asarray(r, dtype=float)
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,):
        raise ValueError(f"motor_pulley_radius must be a scalar or have {n} entries, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0.0):
        raise ValueError(f"motor_pulley_radius must be finite and > 0 [m], got {arr}")
    return arr


# ---------------------------------------------------------------------------
