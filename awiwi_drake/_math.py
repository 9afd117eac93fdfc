"""Scalar-type-generic math for the law functions.

The laws are written once and evaluated with ``float``, ``AutoDiffXd`` and, where the law allows,
``pydrake.symbolic.Expression`` (numpy object arrays for the latter two).  numpy ufuncs dispatch
element-wise on object arrays; ``max``/``min``/``where`` do not, so they live here.
"""

from __future__ import annotations

import numpy as np
import pydrake.math as _pm

__all__ = ["is_float", "scalar_value", "smax", "smin", "clip", "positive_part", "asarray_like",
           "where_positive", "symbolic_vector", "Tangent"]


def is_float(x) -> bool:
    """True when ``x`` is a float scalar or a non-object numpy array."""
    if isinstance(x, np.ndarray):
        return x.dtype != object
    return isinstance(x, (float, int, np.floating, np.integer))


def scalar_value(x):
    """The float value of a number, a one-entry array, an ``AutoDiffXd`` or a :class:`Tangent`, for branch
    decisions and range checks; None for a symbolic ``Expression`` (it has no value)."""
    if isinstance(x, (float, int)):
        return float(x)
    if isinstance(x, Tangent):
        return scalar_value(x.v)
    if isinstance(x, np.ndarray):
        x = x.reshape(-1)[0]
    if is_float(x):
        return float(x)
    return float(x.value()) if hasattr(x, "value") else None


def _binary(fn_float, fn_obj, a, b):
    if is_float(a) and is_float(b):
        return fn_float(a, b)
    a_arr, b_arr = np.broadcast_arrays(np.asarray(a, dtype=object), np.asarray(b, dtype=object))
    out = np.empty(a_arr.shape, dtype=object)
    for idx in np.ndindex(a_arr.shape):
        ai, bi = a_arr[idx], b_arr[idx]
        # pydrake.math.max needs both arguments of the same scalar type.
        if isinstance(ai, (int, float, np.floating)) and not isinstance(bi, (int, float, np.floating)):
            ai = type(bi)(float(ai))
        elif isinstance(bi, (int, float, np.floating)) and not isinstance(ai, (int, float, np.floating)):
            bi = type(ai)(float(bi))
        out[idx] = fn_obj(ai, bi)
    return out[()] if out.shape == () else out


def smax(a, b):
    """Element-wise maximum for float, AutoDiffXd and Expression."""
    if isinstance(a, np.ndarray) and a.dtype == float and isinstance(b, float):
        return np.maximum(a, b)  # hot path
    return _binary(np.maximum, _pm.max, a, b)


def smin(a, b):
    """Element-wise minimum for float, AutoDiffXd and Expression."""
    if isinstance(a, np.ndarray) and a.dtype == float and isinstance(b, float):
        return np.minimum(a, b)  # hot path
    return _binary(np.minimum, _pm.min, a, b)


def clip(x, low, high):
    """Element-wise clip to [low, high] (differentiable almost everywhere)."""
    return smin(smax(x, low), high)


def positive_part(x):
    """max(x, 0): the tension-only (slack) nonlinearity."""
    return smax(x, 0.0)


def asarray_like(values, like):
    """numpy array of ``values`` with the dtype of ``like`` (object for AutoDiff/Expression)."""
    return np.asarray(values, dtype=float if is_float(like) else object)


def where_positive(x, a):
    """Element-wise ``a if x > 0 else 0`` for float, AutoDiffXd and Expression.

    Used for quantities that vanish when a tendon is slack (e.g. stiffness).
    The selection itself carries no derivative (it is piecewise constant).
    """
    if is_float(x) and is_float(a):
        return np.where(np.asarray(x) > 0.0, a, 0.0)
    import pydrake.symbolic as _sym
    x_arr, a_arr = np.broadcast_arrays(np.asarray(x, dtype=object), np.asarray(a, dtype=object))
    out = np.empty(x_arr.shape, dtype=object)
    for idx in np.ndindex(x_arr.shape):
        xi, ai = x_arr[idx], a_arr[idx]
        if isinstance(xi, (_sym.Expression, _sym.Variable)) or isinstance(ai, (_sym.Expression, _sym.Variable)):
            xe = xi if isinstance(xi, _sym.Expression) else _sym.Expression(xi)
            ae = ai if isinstance(ai, _sym.Expression) else _sym.Expression(ai)
            out[idx] = _sym.if_then_else(xe > 0.0, ae, _sym.Expression(0.0))
        else:
            xv = xi.value() if hasattr(xi, "value") else float(xi)
            out[idx] = ai if xv > 0.0 else 0.0 * ai
    return out[()] if out.shape == () else out


def symbolic_vector(prefix: str, size: int):
    """``(variables, expressions)``: ``size`` new symbolic variables ``<prefix>0, <prefix>1, ...`` and the object
    array of their ``Expression`` s (the inputs of a law traced on symbolic variables)."""
    import pydrake.symbolic as _sym
    v = [_sym.Variable(f"{prefix}{i}") for i in range(size)]
    return v, np.array([_sym.Expression(a) for a in v], dtype=object)


class Tangent:
    """Forward-mode pair ``(v, d)``: a value of any scalar type T and its derivative(s) ``d``.

    Differentiates a closed-form function once, exactly, for float, AutoDiffXd and Expression alike (Drake's
    AutoDiffXd cannot nest, so an AutoDiffXd-generic Jacobian such as the wrist's ``P(q) = dh/dq`` needs this
    outer layer).  Supports ``+ - * /`` and ``sin``, ``cos``, ``sqrt``, ``arctan2`` (numpy ufuncs call them).
    """

    __slots__ = ("v", "d")

    def __init__(self, v, d):
        self.v = v
        self.d = d

    @staticmethod
    def _lift(o):
        return o if isinstance(o, Tangent) else Tangent(o, 0.0)

    def __add__(self, o):
        if isinstance(o, np.ndarray):
            return NotImplemented
        o = Tangent._lift(o)
        return Tangent(self.v + o.v, self.d + o.d)

    __radd__ = __add__

    def __sub__(self, o):
        if isinstance(o, np.ndarray):
            return NotImplemented
        o = Tangent._lift(o)
        return Tangent(self.v - o.v, self.d - o.d)

    def __rsub__(self, o):
        if isinstance(o, np.ndarray):
            return NotImplemented
        return Tangent._lift(o) - self

    def __neg__(self):
        return Tangent(-self.v, -self.d)

    def __mul__(self, o):
        if isinstance(o, np.ndarray):
            return NotImplemented
        if not isinstance(o, Tangent):
            return Tangent(self.v * o, self.d * o)
        return Tangent(self.v * o.v, self.d * o.v + self.v * o.d)

    __rmul__ = __mul__

    def __truediv__(self, o):
        if isinstance(o, np.ndarray):
            return NotImplemented
        if not isinstance(o, Tangent):
            return Tangent(self.v / o, self.d / o)
        q = self.v / o.v
        return Tangent(q, (self.d - q * o.d) / o.v)

    def __rtruediv__(self, o):
        if isinstance(o, np.ndarray):
            return NotImplemented
        return Tangent._lift(o) / self

    def sin(self):
        return Tangent(np.sin(self.v), np.cos(self.v) * self.d)

    def cos(self):
        return Tangent(np.cos(self.v), -np.sin(self.v) * self.d)

    def sqrt(self):
        r = np.sqrt(self.v)
        return Tangent(r, self.d / (2.0 * r))

    def arctan2(self, x):
        x = Tangent._lift(x)
        return Tangent(np.arctan2(self.v, x.v), (x.v * self.d - self.v * x.d) / (x.v * x.v + self.v * self.v))
