"""The one finite-difference helper of the test suite.

Tests compare AutoDiffXd derivatives (and closed forms) against central
differences computed here: :func:`fd_jacobian` for a function of a vector,
:func:`autodiff_jacobian` for the same function evaluated on AutoDiffXd, and
:func:`check_system_autodiff_matches_fd` for a LeafSystem or Diagram (time
derivatives and every output port, with respect to state and inputs).
"""

from __future__ import annotations

import numpy as np
from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, InitializeAutoDiff


def fd_jacobian(fun, x, h=None):
    """Central-difference Jacobian ``d fun / d x`` (rows: outputs, columns: entries of ``x``).

    ``h`` defaults to ``1e-7 max(1, |x_j|)`` per entry (about the cube root of the float
    epsilon relative to the entry, where the central difference's truncation and round-off
    errors balance).
    """
    x = np.asarray(x, dtype=float).ravel()
    steps = 1e-7 * np.maximum(1.0, np.abs(x)) if h is None else np.broadcast_to(np.asarray(h, float), x.shape)
    cols = []
    for j in range(x.size):
        e = np.zeros_like(x)
        e[j] = steps[j]
        cols.append((np.ravel(np.asarray(fun(x + e), float)) - np.ravel(np.asarray(fun(x - e), float)))
                    / (2.0 * steps[j]))
    return np.stack(cols, axis=-1)


def autodiff_jacobian(fun, x):
    """Jacobian of ``fun`` at ``x`` by forward-mode AutoDiffXd (``fun`` must accept object arrays)."""
    xa = InitializeAutoDiff(np.asarray(x, dtype=float).ravel()).ravel()
    y = np.atleast_1d(np.asarray(fun(xa), dtype=object)).ravel()
    return ExtractGradient(y).reshape(y.size, xa.size)


def assert_jacobians_close(J, J_ref, rtol=1e-6, name=""):
    """``J`` equals ``J_ref`` to ``rtol`` relative to the largest entry of ``J_ref`` (at least 1)."""
    J, J_ref = np.asarray(J, float), np.asarray(J_ref, float)
    scale = max(1.0, float(np.max(np.abs(J_ref)))) if J_ref.size else 1.0
    np.testing.assert_allclose(J, J_ref, rtol=rtol, atol=rtol * scale, err_msg=f"Jacobian {name}")


def assert_symbolic_matches_float(system, x, inputs: dict, rtol=1e-12):
    """``ToSymbolic()`` converts ``system`` and, evaluated at the numbers ``x`` / ``inputs``, its time
    derivatives and every output equal the float system's (the laws pass Expression through)."""
    from pydrake.symbolic import Expression
    sym = system.ToSymbolic()
    x = np.asarray(x, dtype=float).ravel()

    def evaluate(sys_, lift):
        ctx = sys_.CreateDefaultContext()
        if x.size:
            ctx.SetContinuousState(lift(x))
        for n, v in inputs.items():
            sys_.GetInputPort(n).FixValue(ctx, lift(np.ravel(np.asarray(v, dtype=float))))
        out = [sys_.EvalTimeDerivatives(ctx).CopyToVector()] if x.size else []
        return out + [np.asarray(sys_.get_output_port(i).Eval(ctx)) for i in range(sys_.num_output_ports())]
    ref = evaluate(system, lambda a: a)
    got = evaluate(sym, lambda a: np.array([Expression(float(e)) for e in a], dtype=object))
    for r, g in zip(ref, got):
        np.testing.assert_allclose([e.Evaluate() for e in np.ravel(g)], np.ravel(r), rtol=rtol,
                                   atol=rtol * max(1.0, float(np.max(np.abs(r), initial=0.0))))


def system_jacobians(system, x, inputs: dict, *, wrt=None, ad=None, outputs=None, discrete_state=None):
    """AutoDiffXd and finite-difference Jacobians of a system's time derivatives (when it has
    continuous state) and its output ports, with respect to ``[x; inputs in wrt...]``.

    ``wrt`` names the inputs to differentiate by (default: all of ``inputs``; the others are
    fixed at their values). Returns ``{name: (J_autodiff, J_fd)}`` with ``name`` ``"xdot"`` or an
    output port's name. ``discrete_state`` (float) is set in every context (not differentiated).
    """
    ad = system.ToAutoDiffXd() if ad is None else ad
    assert ad is not None, f"{system.get_name()} does not convert to AutoDiffXd"
    x = np.asarray(x, dtype=float).ravel()
    names = list(inputs) if wrt is None else list(wrt)
    fixed = {n: np.ravel(np.asarray(v, dtype=float)) for n, v in inputs.items() if n not in names}
    flat = np.concatenate([x] + [np.ravel(np.asarray(inputs[n], dtype=float)) for n in names])
    offs = np.cumsum([0, x.size] + [np.size(inputs[n]) for n in names])
    ports = [system.get_output_port(i).get_name() for i in range(system.num_output_ports())] \
        if outputs is None else list(outputs)

    def evaluate(sys_, v, autodiff):
        ctx = sys_.CreateDefaultContext()
        xx = v[offs[0]:offs[1]]
        if xx.size:
            ctx.SetContinuousState(xx)
        lift = (lambda a: np.array([AutoDiffXd(float(e)) for e in a], dtype=object)) if autodiff else (lambda a: a)
        if discrete_state is not None:
            ctx.SetDiscreteState(lift(np.asarray(discrete_state, float)))
        for i, n in enumerate(names):
            sys_.GetInputPort(n).FixValue(ctx, v[offs[i + 1]:offs[i + 2]])
        for n, value in fixed.items():
            sys_.GetInputPort(n).FixValue(ctx, lift(value))
        out = {}
        if xx.size:
            out["xdot"] = sys_.EvalTimeDerivatives(ctx).CopyToVector()
        for p in ports:
            out[p] = np.asarray(sys_.GetOutputPort(p).Eval(ctx))
        return out

    za = InitializeAutoDiff(flat).ravel()
    grads = {}
    for k, v in evaluate(ad, za, True).items():
        g = ExtractGradient(np.asarray(v, dtype=object))
        grads[k] = g.reshape(np.size(v), flat.size) if g.size else np.zeros((np.size(v), flat.size))
    result = {}
    for key in grads:
        J_fd = fd_jacobian(lambda v, key=key: evaluate(system, v, False)[key], flat)
        result[key] = (grads[key], J_fd.reshape(grads[key].shape))
    return result


def check_system_autodiff_matches_fd(system, x, inputs: dict, rtol=1e-5, **kw):
    """Assert AutoDiffXd = central differences for every Jacobian of :func:`system_jacobians`."""
    jac = system_jacobians(system, x, inputs, **kw)
    for key, (J_ad, J_fd) in jac.items():
        assert_jacobians_close(J_ad, J_fd, rtol=rtol, name=key)
    return jac


def autodiff_vs_fd(system, inputs: dict, output: str = "motor_torque", state=None):
    """(J_autodiff, J_fd) of one output port w.r.t. the concatenated ``inputs`` of a stateless (or
    discrete-state, ``state``) system."""
    return system_jacobians(system, [], inputs, outputs=[output], discrete_state=state)[output]
