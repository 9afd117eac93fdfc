"""Nonlinear spring mechanism (thesis ch. 4): spring laws and ``SpringBank_``.

Three spring laws share one interface (``force(x)``, ``stiffness(x)``,
``inverse_force(f)``, ``supports_symbolic``):

* :class:`LeverSpringMechanism` - the lever + linear spring geometry of
  Fig 4.6 / Table 4.1 (tangent-alpha type: stiffness rises with force). Exact,
  float and AutoDiffXd.
* :class:`PolynomialSpring` - the calibration polynomial ``f = sum c_k x^k``
  (the thesis's real-time form); float, AutoDiffXd and Expression. The rigs
  use a polynomial fitted to the lever mechanism in series with the tendon.
* :class:`LinearSpring`.

All are tension-only: ``f = 0`` for ``x <= 0`` (slack).
"""

from __future__ import annotations

import functools
import math
import sys

import numpy as np
from pydrake.autodiffutils import AutoDiffXd
from pydrake.systems.framework import LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem
from pydrake.symbolic import Expression

from awiwi_drake._math import asarray_like, is_float, positive_part, smin, where_positive
from awiwi_drake.components.friction import dahl_rate
from awiwi_drake.parameters.components import (
    HysteresisParams, LinearSpringParams, PolynomialSpringParams, SpringMechanismGeometry, TendonParams)

__all__ = [
    "PolynomialSpring",
    "LinearSpring",
    "AntagonisticPairSpring",
    "LeverSpringMechanism",
    "hysteresis_rate",
    "SpringBank_",
    "SpringBank",
    "TendonSprings",
    "tendon_spring",
]


class PolynomialSpring:
    """Calibration polynomial ``f(x) = sum_{k>=1} c_k x^k`` for ``0 < x <= x_max``.

    Slack (``x <= 0``): ``f = 0``. Beyond the calibrated range ``x_max =
    max_elongation`` the curve continues as its tangent (C1, increasing), so a
    polynomial fit never turns over outside the data; the simulation monitors
    report when a tendon leaves the calibrated range (``spring_overrange``).
    """

    supports_symbolic = True

    def __init__(self, params: PolynomialSpringParams | tuple | list):
        if not isinstance(params, PolynomialSpringParams):
            params = PolynomialSpringParams(coefficients=tuple(params))
        self.params = params
        self.coefficients = np.asarray(params.coefficients, dtype=float)
        self.max_elongation = xm = params.max_elongation
        self._powers = np.arange(1, len(self.coefficients) + 1)
        self._k = self.coefficients * self._powers                     # f' coefficients (x^(k-1))
        self.max_force = float(xm * self._horner(xm, self.coefficients))
        self._k_end = float(self._horner(xm, self._k))

    def __repr__(self):
        return f"PolynomialSpring(coefficients={tuple(self.params.coefficients)}, max_elongation={self.max_elongation})"

    @staticmethod
    def _horner(xp, coeffs):
        acc = coeffs[-1] + 0.0 * xp
        for c in coeffs[-2::-1]:
            acc = acc * xp + c
        return acc

    def _split(self, x):
        """(x clipped to [0, x_max], elongation beyond x_max)."""
        return smin(positive_part(x), self.max_elongation), positive_part(x - self.max_elongation)

    def force(self, x):
        """Tendon force [N] at elongation ``x`` [m] (0 when slack, tangent beyond x_max)."""
        if isinstance(x, np.ndarray) and x.dtype == float and x.ndim == 1:
            # Hot path (float simulation): one power table and a dot product, ~4 us for any N.
            xc = np.minimum(np.maximum(x, 0.0), self.max_elongation)
            return (xc[:, None] ** self._powers) @ self.coefficients + self._k_end * np.maximum(x - self.max_elongation, 0.0)
        xc, beyond = self._split(x)
        return xc * self._horner(xc, self.coefficients) + self._k_end * beyond

    def stiffness(self, x):
        """``df/dx`` [N/m] (0 when slack, constant beyond x_max)."""
        xc, _ = self._split(x)
        return where_positive(x, self._horner(xc, self._k))

    def stiffness_derivative(self, x):
        """``d^2f/dx^2`` [N/m^2] (0 when slack and beyond x_max)."""
        n = len(self.coefficients)
        xc, _ = self._split(x)
        if n < 2:
            return 0.0 * xc
        k = np.arange(2, n + 1)
        return where_positive(x, where_positive(self.max_elongation - x,
                                                self._horner(xc, self.coefficients[1:] * k * (k - 1))))

    def energy(self, x):
        """Stored energy ``int_0^x f`` [J] (0 when slack)."""
        xc, e = self._split(x)
        inside = xc * xc * self._horner(xc, self.coefficients / (self._powers + 1))
        return inside + (self.max_force + 0.5 * self._k_end * e) * e

    def inverse_force(self, f):
        """Elongation [m] at which the spring carries force ``f`` [N] (float, vectorised)."""
        f = np.asarray(f, dtype=float)
        if np.any(f < 0) or not np.all(np.isfinite(f)):
            raise ValueError(f"PolynomialSpring.inverse_force: force must be finite and >= 0 [N], got {f}")
        return _monotone_inverse(self.force, self.stiffness, f, x_hi=self.max_elongation)


class LinearSpring:
    """Linear spring ``f = k x``; tension-only (``f = k max(x, 0)``) unless ``tension_only=False``.

    The two-sided form is the torsional spring of the flexible joint (12.8).
    """

    supports_symbolic = True

    def __init__(self, params: LinearSpringParams | float, *, tension_only: bool = True):
        if not isinstance(params, LinearSpringParams):
            params = LinearSpringParams(stiffness=float(params))
        self.params = params
        self.k = params.stiffness
        self.tension_only = tension_only
        self.max_elongation = math.inf

    def __repr__(self):
        return f"LinearSpring(k={self.k}, tension_only={self.tension_only})"

    def force(self, x):
        return self.k * (positive_part(x) if self.tension_only else x)

    def stiffness(self, x):
        return where_positive(x, self.k + 0.0 * x) if self.tension_only else self.k + 0.0 * x

    def stiffness_derivative(self, x):
        return 0.0 * x

    def energy(self, x):
        """Stored energy [J]."""
        xe = positive_part(x) if self.tension_only else x
        return 0.5 * self.k * xe * xe

    def inverse_force(self, f):
        f = np.asarray(f, dtype=float)
        if (self.tension_only and np.any(f < 0)) or not np.all(np.isfinite(f)):
            raise ValueError(f"LinearSpring.inverse_force: force must be finite (and >= 0 if tension-only), got {f}")
        return f / self.k


class AntagonisticPairSpring:
    """Torsional spring of two pretensioned tension-only springs on a pulley of radius r.

    ``phi(d) = r (f(x0 + r d) - f(x0 - r d))`` with ``x0 = f^-1(pretension)``: the
    effective nonlinear joint spring of an antagonistic pair (ch. 15.4 writes
    ``tau = phi(theta - q)``). Odd, increasing, and stiffening with deflection
    for a convex ``f``.
    """

    def __init__(self, spring, pretension: float, radius: float):
        if not pretension > 0 or not radius > 0:
            raise ValueError(f"AntagonisticPairSpring: pretension = {pretension} N and radius = {radius} m must be > 0")
        self.spring, self.pretension, self.r = spring, float(pretension), float(radius)
        self.x0 = float(np.ravel(spring.inverse_force(np.array([pretension])))[0])
        self.supports_symbolic = getattr(spring, "supports_symbolic", False)
        self.tension_only = False
        self.max_elongation = math.inf

    def force(self, d):
        r = self.r
        return r * (self.spring.force(self.x0 + r * d) - self.spring.force(self.x0 - r * d))

    def stiffness(self, d):
        r = self.r
        return r * r * (self.spring.stiffness(self.x0 + r * d) + self.spring.stiffness(self.x0 - r * d))

    def energy(self, d):
        """Stored energy relative to d = 0 [J] (needs the inner spring's ``energy``)."""
        r = self.r
        return (self.spring.energy(self.x0 + r * d) + self.spring.energy(self.x0 - r * d)
                - 2 * self.spring.energy(self.x0))

    def stiffness_derivative(self, d):
        r = self.r
        return r ** 3 * (self.spring.stiffness_derivative(self.x0 + r * d)
                         - self.spring.stiffness_derivative(self.x0 - r * d))

    def inverse_force(self, tau):
        tau = np.atleast_1d(np.asarray(tau, dtype=float))
        out = np.empty_like(tau)
        for i, t in enumerate(tau):  # odd and increasing: bisection on a bracket
            lo, hi = -1.0, 1.0
            while self.force(hi) < t:
                hi *= 2
            while self.force(lo) > t:
                lo *= 2
            for _ in range(200):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if self.force(mid) < t else (lo, mid)
            out[i] = 0.5 * (lo + hi)
        return out if out.size > 1 else out[0]


def _monotone_inverse(fun, dfun, target, x_hi, iters=60):
    """Solve ``fun(x) = target`` for increasing ``fun`` on [0, inf) (safeguarded Newton)."""
    target = np.atleast_1d(np.asarray(target, dtype=float))
    lo = np.zeros_like(target)
    hi = np.full_like(target, x_hi if math.isfinite(x_hi) else 1.0)
    for _ in range(60):  # expand the bracket if needed (extrapolation beyond calibration)
        short = fun(hi) < target
        if not np.any(short):
            break
        hi = np.where(short, 2 * hi, hi)
    x = 0.5 * (lo + hi)
    for _ in range(iters):
        fx = fun(x) - target
        if np.all(np.abs(fx) <= 1e-13 * np.maximum(1.0, np.abs(target))):
            break
        lo = np.where(fx < 0, x, lo)
        hi = np.where(fx > 0, x, hi)
        k = dfun(x)
        step = np.where(k > 0, fx / np.where(k > 0, k, 1.0), 0.0)
        xn = x - step
        bad = (xn < lo) | (xn > hi) | (k <= 0)
        x = np.where(fx == 0, x, np.where(bad, 0.5 * (lo + hi), xn))
    return x if x.size > 1 else x[0]


class LeverSpringMechanism:
    """Lever + linear spring of Fig 4.6 / Table 4.1 (quasi-static, frictionless).

    Geometry (see :class:`SpringMechanismGeometry`): motor-side pulley
    ``M = (-s/2, 0)``, fixed pulley ``F = (s/2, 0)``, lever pivot
    ``C = (c, 0)``, lever pulley ``P(th) = C + l (cos(a0 - th), sin(a0 - th))``
    with ``a0 = lever_straight_angle``, spring point on the opposite arm
    ``Q(th) = C - l_s (cos(a0 - th), sin(a0 - th))``, anchor ``S``.

    * tendon length in the mechanism ``dL(th) = |P - M| + |F - P|``
    * elongation (tendon released by the mechanism) ``x(th) = dL(0) - dL(th)``
    * spring length ``s(th) = |Q - S|``, free at ``th = 0``
    * virtual work: ``f x'(th) = K (s - s(0)) s'(th)``.

    ``force(x)`` inverts ``x(th)``; AutoDiffXd inputs get ``df/dx = f'(th) / x'(th)``.
    """

    supports_symbolic = False

    def __init__(self, geometry: SpringMechanismGeometry = SpringMechanismGeometry()):
        if not isinstance(geometry, SpringMechanismGeometry):
            raise ValueError(f"LeverSpringMechanism: geometry must be SpringMechanismGeometry, got {type(geometry).__name__}")
        self.geometry = g = geometry
        self._M = np.array([-g.pulley_spacing / 2, 0.0])
        self._F = np.array([g.pulley_spacing / 2, 0.0])
        self._C = np.array([g.pivot_offset, 0.0])
        self._S = np.asarray(g.spring_anchor, dtype=float)
        self._dL0 = float(self.tendon_length(0.0))
        self._s0 = float(self._spring_length(0.0))
        self.max_elongation = float(self.elongation_at_angle(g.max_lever_angle))
        self._check_monotonic()

    def _check_monotonic(self) -> None:
        """The geometry must release tendon and load the spring monotonically up to the stop."""
        th = np.linspace(0.0, self.geometry.max_lever_angle, 200)[1:]
        x = self.elongation_at_angle(th)
        if np.any(np.diff(np.concatenate([[0.0], x])) <= 0):
            raise ValueError("SpringMechanismGeometry: the tendon length dL must shrink monotonically with the lever "
                             "angle up to max_lever_angle (check pivot_offset, lever_length, lever_straight_angle)")
        f = np.array([self._f_exact(float(t)) for t in th[::10]])
        if np.any(f <= 0) or np.any(np.diff(f) <= 0):
            raise ValueError("SpringMechanismGeometry: the tendon force must rise with the lever angle up to "
                             "max_lever_angle (check spring_anchor, spring_arm, spring_constant)")

    # -- geometry, generic in the scalar type of th ------------------------------
    def _points(self, th):
        g = self.geometry
        a = g.lever_straight_angle - th
        ca, sa = np.cos(a), np.sin(a)
        P = (self._C[0] + g.lever_length * ca, self._C[1] + g.lever_length * sa)
        Q = (self._C[0] - g.spring_arm * ca, self._C[1] - g.spring_arm * sa)
        return P, Q

    def tendon_length(self, th):
        """dL(th) [m]: tendon length between the motor-side and the fixed pulley."""
        P, _ = self._points(th)
        M, F = self._M, self._F
        return (np.sqrt((P[0] - M[0]) ** 2 + (P[1] - M[1]) ** 2)
                + np.sqrt((F[0] - P[0]) ** 2 + (F[1] - P[1]) ** 2))

    def _spring_length(self, th):
        _, Q = self._points(th)
        return np.sqrt((Q[0] - self._S[0]) ** 2 + (Q[1] - self._S[1]) ** 2)

    def elongation_at_angle(self, th):
        """x(th) = dL(0) - dL(th) [m]."""
        return self._dL0 - self.tendon_length(th)

    def spring_energy_at_angle(self, th):
        """Potential energy of the linear spring [J] at lever angle th."""
        return 0.5 * self.geometry.spring_constant * (self._spring_length(th) - self._s0) ** 2

    def force_at_angle(self, th):
        """Tendon force [N] in equilibrium at lever angle ``th`` [rad] (float, vectorised)."""
        th = np.asarray(th, dtype=float)
        out = np.array([self._f_exact(t) if t > 0 else 0.0 for t in th.ravel()], dtype=float)
        return out.reshape(th.shape) if th.shape else out[0]

    def _force_and_slope_at_angle(self, t: float):
        """(f, df/dth, dx/dth) at the float lever angle ``t``.

        ``f`` and ``dx/dth`` are exact (AutoDiffXd through the closed-form
        geometry); ``df/dth`` is a central difference of the exact ``f``
        (h = 1e-6 rad, ~1e-9 relative error), one-sided at ``t = 0``.
        """
        h = 1e-6
        f = self._f_exact(t) if t > 0 else 0.0
        if t > h:
            fp = (self._f_exact(t + h) - self._f_exact(t - h)) / (2 * h)
        else:
            fp = (self._f_exact(t + h) - f) / h
        xp = self.elongation_at_angle(AutoDiffXd(t, np.array([1.0]))).derivatives()[0]
        return f, fp, xp

    def _f_exact(self, t: float) -> float:
        th = AutoDiffXd(t, np.array([1.0]))
        xp = self.elongation_at_angle(th).derivatives()[0]
        s = self._spring_length(th)
        return self.geometry.spring_constant * (s.value() - self._s0) * s.derivatives()[0] / xp

    def angle_at_elongation(self, x):
        """Lever angle [rad] at elongation ``x`` [m] (float, vectorised; x >= 0)."""
        x = np.asarray(x, dtype=float)
        th_hi = self.geometry.lever_straight_angle * (1 - 1e-9)
        xfun, h = self.elongation_at_angle, 1e-7
        xs = np.atleast_1d(x)
        if np.any(xs < 0) or np.any(xs >= float(xfun(th_hi))):
            raise ValueError(f"LeverSpringMechanism: elongation {x} outside [0, {float(xfun(th_hi)):.6g}) m")
        return _monotone_inverse(xfun, lambda t: (xfun(t + h) - xfun(t - h)) / (2 * h), xs, x_hi=th_hi)

    # -- spring-law interface -----------------------------------------------------
    def force(self, x):
        """Tendon force [N] at elongation ``x`` [m]; 0 when slack. float or AutoDiffXd."""
        return self._eval(x, want="force")

    def stiffness(self, x):
        """df/dx [N/m] at elongation ``x`` [m]; 0 when slack."""
        return self._eval(x, want="stiffness")

    def _eval(self, x, want):
        if not is_float(x):
            arr = np.asarray(x, dtype=object)
            if any(isinstance(v, Expression) for v in arr.ravel()):
                raise ValueError("LeverSpringMechanism does not support symbolic Expressions; "
                                 "use .to_polynomial() (the calibration polynomial) for symbolic/C++ use")
            vals = np.array([v.value() for v in arr.ravel()])
            f, k = self._force_stiffness_float(vals)
            if want == "stiffness":  # d(stiffness)/dx by a central difference of the exact stiffness
                h = 1e-9
                dk = (self._force_stiffness_float(vals + h)[1] - self._force_stiffness_float(np.maximum(vals - h, 0))[1]) \
                    / (vals + h - np.maximum(vals - h, 0))
            res = np.empty(arr.size, dtype=object)
            for i, v in enumerate(arr.ravel()):
                val = f[i] if want == "force" else k[i]
                slope = k[i] if want == "force" else dk[i]
                res[i] = AutoDiffXd(val, slope * v.derivatives())
            return res.reshape(arr.shape) if arr.shape else res[0]
        xv = np.asarray(x, dtype=float)
        f, k = self._force_stiffness_float(np.atleast_1d(xv))
        out = f if want == "force" else k
        return out.reshape(xv.shape) if xv.shape else out[0]

    def _force_stiffness_float(self, x: np.ndarray):
        f = np.zeros_like(x)
        k = np.zeros_like(x)
        pos = x > 0
        if np.any(pos):
            th = np.atleast_1d(self.angle_at_elongation(x[pos]))
            vals = [self._force_and_slope_at_angle(t) for t in th]
            f[pos] = [v[0] for v in vals]
            k[pos] = [v[1] / v[2] for v in vals]
        return f, k

    def inverse_force(self, f):
        """Elongation [m] carrying force ``f`` [N] (float, vectorised)."""
        f = np.asarray(f, dtype=float)
        if np.any(f < 0) or not np.all(np.isfinite(f)):
            raise ValueError(f"LeverSpringMechanism.inverse_force: force must be finite and >= 0 [N], got {f}")
        th_hi = self.geometry.lever_straight_angle * (1 - 1e-6)

        def dfdth(t):
            return np.array([self._force_and_slope_at_angle(float(ti))[1] for ti in np.atleast_1d(t)])

        th = _monotone_inverse(lambda t: self.force_at_angle(t), dfdth, np.atleast_1d(f), x_hi=th_hi)
        x = self.elongation_at_angle(np.atleast_1d(th))
        return x if f.shape else float(np.ravel(x)[0])

    def sample_curve(self, max_force: float = 180.0, num: int = 400):
        """(lever_angle, elongation, force, stiffness) arrays from 0 to ``max_force``."""
        th_max = float(np.ravel(self.angle_at_elongation(self.inverse_force(np.array([max_force]))))[0])
        th = np.linspace(0.0, th_max, num)
        vals = [self._force_and_slope_at_angle(t) for t in th]
        f = np.array([v[0] for v in vals])
        k = np.array([v[1] / v[2] for v in vals])
        return th, self.elongation_at_angle(th), f, k

    def to_polynomial(self, degree: int = 6, *, max_force: float = 180.0,
                      tendon: TendonParams | None = None) -> PolynomialSpring:
        """Calibration polynomial of this mechanism (optionally in series with a tendon).

        Samples the curve from 0 to ``max_force``; with ``tendon`` the elongation
        includes the tendon stretch ``f / k_t`` (ch. 4: the calibration is done on
        the mounted tendon). Least squares on ``f = sum_{k=1..degree} c_k x^k``.
        """
        return _fit_polynomial_cached(self.geometry, int(degree), float(max_force), tendon)


@functools.lru_cache(maxsize=32)
def _fit_polynomial_cached(geometry, degree, max_force, tendon):
    from awiwi_drake.components.tendon import tendon_stiffness

    lever = LeverSpringMechanism(geometry)
    _, x, f, _ = lever.sample_curve(max_force=max_force, num=600)
    if tendon is not None:
        x = x + f / tendon_stiffness(tendon)
    x_max = float(x[-1])
    s = x / x_max
    A = np.stack([s ** k for k in range(1, degree + 1)], axis=1)
    w = 1.0 / np.sqrt(1.0 + f / 20.0)  # even relative accuracy at low and high force
    c_scaled, *_ = np.linalg.lstsq(A * w[:, None], f * w, rcond=None)
    coeffs = tuple(float(c_scaled[k - 1] / x_max ** k) for k in range(1, degree + 1))
    return PolynomialSpring(PolynomialSpringParams(coefficients=coeffs, max_elongation=x_max))


@functools.lru_cache(maxsize=32)
def tendon_spring(spring_params) -> PolynomialSpring:
    """The spring law a rig uses, from its :class:`SpringModelParams` (one law object per parameter set).

    Raises ValueError when ``max_force`` is beyond what the lever carries at its
    mechanical stop (``geometry.max_lever_angle``).
    """
    lever = LeverSpringMechanism(spring_params.geometry)
    f_stop = float(lever.force_at_angle(spring_params.geometry.max_lever_angle))
    if spring_params.max_force > f_stop:
        raise ValueError(f"SpringModelParams.max_force = {spring_params.max_force} N is beyond the lever's "
                         f"mechanical stop ({f_stop:.1f} N at geometry.max_lever_angle)")
    return lever.to_polynomial(
        spring_params.polynomial_degree, max_force=spring_params.max_force,
        tendon=spring_params.tendon if spring_params.include_tendon else None)


class TendonSprings:
    """One spring law per tendon of a drive (the hand's calibration table, ch. 4), evaluated element-wise.

    ``laws[i]`` is the law of tendon ``i`` (objects with ``force(x)``, ``stiffness(x)``,
    ``inverse_force(f)``); tendons that share a law object are evaluated together.  The methods take one
    value per tendon; float, AutoDiffXd and (when every law supports it) Expression arrays pass through,
    so a :class:`SpringBank_` takes a bank in place of one law.  This is the one place a vector of tendons
    meets its laws.
    """

    def __init__(self, laws):
        laws = tuple(laws.laws if isinstance(laws, TendonSprings) else laws)
        if not laws:
            raise ValueError("TendonSprings: give one spring law per tendon (got none)")
        for i, law in enumerate(laws):
            if not all(hasattr(law, a) for a in ("force", "stiffness", "inverse_force")):
                raise ValueError(f"TendonSprings: laws[{i}] = {law!r} is not a spring law "
                                 "(needs force(x), stiffness(x), inverse_force(f))")
        self.laws = laws
        groups: dict = {}
        for i, law in enumerate(laws):
            groups.setdefault(id(law), (law, []))[1].append(i)
        self.groups = tuple((law, np.array(ix, dtype=int)) for law, ix in groups.values())
        self.supports_symbolic = all(getattr(law, "supports_symbolic", False) for law in laws)
        self.max_elongation = np.array([float(getattr(law, "max_elongation", math.inf)) for law in laws])

    def __len__(self) -> int:
        return len(self.laws)

    def __getitem__(self, i):
        return self.laws[i]

    def __iter__(self):
        return iter(self.laws)

    def __repr__(self):
        return f"TendonSprings({len(self.laws)} tendons, {len(self.groups)} distinct laws)"

    @property
    def uniform(self) -> bool:
        """True when every tendon has the same law object."""
        return len(self.groups) == 1

    def subset(self, index) -> "TendonSprings":
        """The laws of the tendons ``index`` (a slice or integer indices), e.g. one finger's."""
        idx = np.arange(len(self.laws))[index]
        return TendonSprings([self.laws[int(i)] for i in np.atleast_1d(idx)])

    def _eval(self, method: str, x):
        x = np.asarray(x) if isinstance(x, np.ndarray) else np.asarray(x, dtype=object if not is_float(x) else float)
        if x.shape != (len(self.laws),):
            raise ValueError(f"TendonSprings.{method}: expected one value per tendon ({len(self.laws)}), "
                             f"got shape {x.shape}")
        if self.uniform:
            return asarray_like(getattr(self.laws[0], method)(x), x)
        out = np.empty(x.shape, dtype=float if is_float(x) else object)
        for law, ix in self.groups:
            out[ix] = asarray_like(getattr(law, method)(x[ix]), x)
        return out

    def force(self, x):
        """Tendon forces [N] at the elongations ``x`` [m], each with its tendon's law."""
        return self._eval("force", x)

    def stiffness(self, x):
        """``df_i/dx_i`` [N/m] of each tendon's law."""
        return self._eval("stiffness", x)

    def stiffness_derivative(self, x):
        """``d^2 f_i/dx_i^2`` [N/m^2] of each tendon's law."""
        return self._eval("stiffness_derivative", x)

    def energy(self, x):
        """Stored energy [J] of each tendon's spring."""
        return self._eval("energy", x)

    def inverse_force(self, f):
        """Elongations [m] at which each tendon's spring carries ``f_i`` [N] (float)."""
        f = np.asarray(f, dtype=float)
        if f.shape != (len(self.laws),):
            raise ValueError(f"TendonSprings.inverse_force: expected one force per tendon ({len(self.laws)}), "
                             f"got shape {f.shape}")
        out = np.empty(f.shape)
        for law, ix in self.groups:
            out[ix] = np.asarray(law.inverse_force(f[ix]), dtype=float)
        return out


def hysteresis_rate(z, x, xdot, f_elastic, p: HysteresisParams):
    """Rate-independent Dahl hysteresis force rate ``dz/dt`` (see :class:`HysteresisParams`).

    ``dz/dt = (xdot / delta) (w - tanh(xdot / v_s) z)``, ``w = beta f_el + z0``
    (:func:`~awiwi_drake.components.friction.dahl_rate`, the friction in the lever): ``z`` tends to
    ``+-w`` on loading/unloading, a loop of full width ``2 w`` around the elastic curve.  ``p`` is one
    :class:`HysteresisParams` or a tuple of one per tendon (``enabled`` false: no loop, ``w = 0``).
    """
    if isinstance(p, tuple):
        on = np.array([h.enabled for h in p], dtype=float)
        return dahl_rate(z, xdot, on * np.array([h.width_ratio for h in p]) * f_elastic
                         + on * np.array([h.width_offset for h in p]), np.array([h.presliding_length for h in p]),
                         np.array([h.smoothing_velocity for h in p]))
    return dahl_rate(z, xdot, p.width_ratio * f_elastic + p.width_offset, p.presliding_length, p.smoothing_velocity)


@TemplateSystem.define("SpringBank_", scope=sys.modules[__name__])
def SpringBank_(T):
    """N tendon spring mechanisms in one system (thesis ch. 4).

    Inputs ``elongation`` (N) [m] and, with hysteresis, ``elongation_rate`` (N) [m/s]; outputs
    ``tendon_force`` (N) [N] (elastic + hysteresis force, 0 when slack) and ``tendon_stiffness`` (N) [N/m]
    (df/dx of the elastic curve).  With hysteresis the system has N states, the hysteresis forces z.
    """

    class Impl(LeafSystem_[T]):
        def _construct(self, spring=None, num_springs: int = 1,
                       hysteresis: HysteresisParams = HysteresisParams(), converter=None):
            LeafSystem_[T].__init__(self, converter)
            if spring is None or not hasattr(spring, "force"):
                raise ValueError("SpringBank: spring must be a spring law (force(x), stiffness(x))")
            if T is Expression and not getattr(spring, "supports_symbolic", False):
                raise ValueError(f"SpringBank: {type(spring).__name__} cannot be evaluated symbolically")
            if int(num_springs) != num_springs or num_springs < 1:
                raise ValueError(f"SpringBank: num_springs = {num_springs!r} must be a positive integer")
            n = int(num_springs)
            self.spring, self.num_springs, self.hysteresis = spring, n, hysteresis
            self._x = self.DeclareVectorInputPort("elongation", n)
            tickets = {self._x.ticket()}
            if hysteresis.enabled:
                self._xd = self.DeclareVectorInputPort("elongation_rate", n)
                self.DeclareContinuousState(n)
                tickets.add(self.all_state_ticket())
            self.DeclareVectorOutputPort("tendon_force", n, self._calc_force, prerequisites_of_calc=tickets)
            self.DeclareVectorOutputPort("tendon_stiffness", n, self._calc_stiffness,
                                         prerequisites_of_calc={self._x.ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.spring, other.num_springs, other.hysteresis, converter=converter)

        def _calc_force(self, context, out):
            x = self._x.Eval(context)
            f = self.spring.force(x)
            if self.hysteresis.enabled:
                z = context.get_continuous_state_vector().CopyToVector()
                f = positive_part(f + z)
            out.SetFromVector(asarray_like(f, x))

        def _calc_stiffness(self, context, out):
            x = self._x.Eval(context)
            out.SetFromVector(asarray_like(self.spring.stiffness(x), x))

        def DoCalcTimeDerivatives(self, context, derivatives):
            if not self.hysteresis.enabled:
                return
            x = self._x.Eval(context)
            xd = self._xd.Eval(context)
            z = context.get_continuous_state_vector().CopyToVector()
            dz = hysteresis_rate(z, x, xd, self.spring.force(x), self.hysteresis)
            derivatives.get_mutable_vector().SetFromVector(dz)

    return Impl


SpringBank = SpringBank_[None]
