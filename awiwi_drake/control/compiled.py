"""Compiled float fast paths of the control laws (the simulation's hot path), one generated module per motor.

The motor's friction (3.8) and ripple (3.5) feed-forward are generated from the law functions
(:func:`~awiwi_drake.components.motor.motor_friction_torque`, :func:`~awiwi_drake.components.motor.motor_ripple_torque`)
by :mod:`awiwi_drake.components.codegen` (``motor_feedforward``); the laws that use them are written once more
here for float arrays (loops, no temporaries), each the twin of a law written for every scalar type and tested
equal to it (tests/test_control_tendon.py, tests/test_fused_chain.py):

* ``force_law`` -- (10.2) over a bank of tendons (:meth:`~awiwi_drake.control.tendon_force.TendonForceLaw.evaluate`):
  the interpolation of :func:`~awiwi_drake.control.tendon_force.interp`'s float bank path (the same index and
  arithmetic), the clamps of ``ForceMap.alpha_of_force`` and ``TendonForceLaw.gains_at``.  Returns -1, or the
  index of the first reference outside its table (the caller raises through the law).
* ``sdre_law`` -- the tendon SDRE bank with held gains (:class:`~awiwi_drake.control.sdre.TendonSdreLaw`, as written
  there): the same interpolation as ``force_law``, the measured force clamped to its table (or the motor angle as the
  state, ``by_angle``); returns as ``force_law``.
* ``backstepping`` -- the 15.5 law of a finger/the hand
  (:meth:`~awiwi_drake.control.finger_backstepping.FingerBacksteppingLaw.terms`, ``variant="antagonistic"``, with or
  without the link torque estimate and its bounded compensation) with polynomial spring laws
  (:class:`~awiwi_drake.components.spring.PolynomialSpring`, one coefficient row per tendon).
"""

from __future__ import annotations

import numba
import numpy as np
import pydrake.symbolic as sym

from awiwi_drake.components import motor_friction_torque, motor_ripple_torque
from awiwi_drake.components.codegen import compile_kernels

__all__ = ["motor_law_kernels", "float_inputs", "joint_feedback"]

_SOURCE = '''
@numba.njit(cache=True, fastmath=False, error_model='numpy')
def _interp1(x, xp, fp, n):
    i = np.searchsorted(xp[:n], x) - 1
    i = min(max(i, 0), n - 2)
    x0 = xp[i]
    f0 = fp[i]
    return f0 + (fp[i + 1] - f0) / (xp[i + 1] - x0) * (x - x0)


@numba.njit(cache=True, fastmath=False, error_model='numpy')
def _first_outside(fd, group, fmax):
    for i in range(fd.shape[0]):
        g = group[i]
        if not (np.isfinite(fd[i]) and fd[i] >= 0.0 and fd[i] <= fmax[g]):
            return i
    return -1


@numba.njit(cache=True, fastmath=False, error_model='numpy')
def _minus_motor_feedforward(tau, w, th, friction_scale, ripple_scale, arg, res):
    arg[0] = w
    arg[1] = th
    motor_feedforward(arg, res)
    if friction_scale > 0:
        tau = tau - friction_scale * res[0]
    if ripple_scale > 0:
        tau = tau - ripple_scale * res[1]
    return tau


@numba.njit(cache=True, fastmath=False, error_model='numpy')
def force_law(fd, f, w, th, vp, group, n, tf, tkp, tkd, ta, kp_fixed, kd_fixed, lo, fmax,
              scheduled, path, feedforward, friction, friction_scale, ripple_scale, r_m, out):
    m = fd.shape[0]
    bad = _first_outside(fd, group, fmax)
    if bad >= 0:
        return bad
    arg = np.empty(2)
    res = np.empty(2)
    for i in range(m):
        g = group[i]
        if scheduled:
            fr = min(max(fd[i], tf[g, 0]), fmax[g])
            kp = _interp1(fr, tf[g], tkp[g], n[g])
            kd = _interp1(fr, tf[g], tkd[g], n[g])
        else:
            kp = kp_fixed[g]
            kd = kd_fixed[g]
        w_el = w[i] + vp[i] / r_m if path else w[i]
        alpha = _interp1(min(max(f[i], lo[g]), fmax[g]), tf[g], ta[g], n[g])
        tau = kp * (fd[i] - f[i]) - kd * (alpha * w_el)
        if feedforward:
            tau = tau + r_m * f[i]
        out[i] = _minus_motor_feedforward(tau, w[i], th[i], friction_scale if friction else 0.0, ripple_scale, arg, res)
    return -1


@numba.njit(cache=True, fastmath=False, error_model='numpy')
def sdre_law(fd, f, w, th, vp, g, group, n, tf, tth, fmax, path, by_angle, friction_scale, ripple_scale, r_m, out):
    m = fd.shape[0]
    bad = _first_outside(fd, group, fmax)
    if bad >= 0:
        return bad
    arg = np.empty(2)
    res = np.empty(2)
    for i in range(m):
        k = group[i]
        theta = th[i] if by_angle else _interp1(min(max(f[i], 0.0), fmax[k]), tf[k], tth[k], n[k])
        err = theta - _interp1(fd[i], tf[k], tth[k], n[k])
        w_el = w[i] + vp[i] / r_m if path else w[i]
        tau = r_m * fd[i] - g[i] * err - g[m + i] * w_el
        out[i] = _minus_motor_feedforward(tau, w[i], th[i], friction_scale, ripple_scale, arg, res)
    return -1


@numba.njit(cache=True, fastmath=False, error_model='numpy')
def _poly(x, c, deg):
    acc = c[deg - 1]
    for j in range(deg - 2, -1, -1):
        acc = acc * x + c[j]
    return acc


@numba.njit(cache=True, fastmath=False, error_model='numpy')
def backstepping(q, v, q_ref, x, th, w, P, S, Sp, W, Minv, Bq, Kp, Kd, K3, K4, f_op, tau_op, r_m, B, friction_scale,
                 coef, dcoef, ddcoef, xmax, kend, link_feedforward, fc, estimate, compensate, C, rise, beta, z0, hold,
                 out):
    m, n = P.shape
    k = S.shape[1]
    deg = coef.shape[1]
    PS = P @ S
    e = Sp @ (q - q_ref)
    ed = Sp @ v
    f = np.empty(m)
    k1 = np.empty(m)
    k2 = np.empty(m)
    for i in range(m):
        xc = min(max(x[i], 0.0), xmax[i])
        f[i] = xc * _poly(xc, coef[i], deg) + kend[i] * max(x[i] - xmax[i], 0.0)
        k1[i] = _poly(xc, dcoef[i], deg) if x[i] > 0.0 else 0.0
        k2[i] = _poly(xc, ddcoef[i], deg) if (x[i] > 0.0 and xmax[i] - x[i] > 0.0) else 0.0
    xd = r_m * w + P @ v
    fd = k1 * xd
    tau = -(PS.T @ f)
    a0 = -(Kp @ e) - Kd @ ed
    if estimate:
        tau = tau - fc
        if compensate:
            lv = np.empty(m)
            for i in range(m):                 # joint_friction_bound: W(f + w) + w, w = beta f + z0; + hold
                fp = max(f[i], 0.0)
                wi = beta[i] * fp + z0[i]
                lv[i] = C[i] + (fp + wi) * rise[i] + wi
            bound = np.abs(PS).T @ lv + hold
            for j in range(k):
                a0[j] = a0[j] + min(max(fc[j], -bound[j]), bound[j])
    edd = Minv @ (tau - Bq @ ed)
    eddd = Minv @ (-(PS.T @ fd) - Bq @ edd)
    a1 = -(Kp @ ed) - Kd @ edd
    a2 = -(Kp @ edd) - Kd @ eddd
    f_des = f_op + W @ (a0 + tau_op + PS.T @ f_op)
    arg = np.empty(2)
    res = np.empty(2)
    wd0 = np.empty(m)
    for i in range(m):
        arg[0] = w[i]
        arg[1] = th[i]
        motor_feedforward(arg, res)
        wd0[i] = (friction_scale * res[0] + res[1] - r_m * f[i]) / B
    f0 = k2 * xd * xd + k1 * r_m * wd0
    if link_feedforward:
        f0 = f0 + k1 * (P @ (S @ edd))
    g = k1 * r_m / B
    z3 = f - f_des
    Wa1 = W @ a1
    beta = Wa1 - K3 * z3 + PS @ ed
    z4 = fd - beta
    beta_d = W @ a2 - K3 * (fd - Wa1) + PS @ edd
    for i in range(m):
        out[i] = (beta_d[i] - f0[i] - z3[i] - K4[i] * z4[i]) / g[i]
    return out
'''


def motor_law_kernels(motor) -> dict:
    """``{"motor_feedforward", "force_law", "sdre_law", "backstepping"}`` compiled for ``motor`` (a
    :class:`~awiwi_drake.parameters.components.MotorParams`; cached on disk by the generated source)."""
    w, th = sym.Variable("omega"), sym.Variable("theta")
    with np.errstate(invalid="ignore"):      # numpy's ufunc on an Expression object reports a spurious FP flag
        laws = (motor_friction_torque(w, motor), motor_ripple_torque(th, motor))
    exprs = [e if isinstance(e, sym.Expression) else sym.Expression(float(e)) for e in laws]
    return compile_kernels({"motor_feedforward": ([[w, th]], exprs)}, tag="control_laws", extra=_SOURCE,
                           extra_names=["force_law", "sdre_law", "backstepping"])


def float_inputs(u, names) -> bool:
    """Every input ``u[name]`` a float64 numpy array (the simulation's hot path; AutoDiffXd takes the law as written)."""
    for nm in names:
        v = u[nm]
        if not (isinstance(v, np.ndarray) and v.dtype == np.float64):
            return False
    return True


@numba.njit(cache=True, fastmath=False, error_model="numpy")
def joint_feedback(Sp, q, v, q_ref, q0, K, Nx, Nu, tau0):
    """:class:`~awiwi_drake.control.joint_stage.JointStateFeedbackLaw` without torque feedback (``K[:, 2:] = 0``:
    PD / impedance), float: ``tau0 + Nu dr - sum_c K_c (z_c - ref_c dr)`` with the law's terms in its order."""
    k, n = Sp.shape
    out = np.empty(k)
    for j in range(k):
        qd = 0.0
        vd = 0.0
        rd = 0.0
        for i in range(n):
            qd += Sp[j, i] * q[i]
            vd += Sp[j, i] * v[i]
            rd += Sp[j, i] * q_ref[i]
        dr = rd - q0[j]
        s = K[j, 0] * ((qd - q0[j]) - Nx[j, 0] * dr)
        s += K[j, 1] * (vd - Nx[j, 1] * dr)
        s += K[j, 2] * (0.0 * vd - Nx[j, 2] * dr)
        s += K[j, 3] * (0.0 * vd - Nx[j, 3] * dr)
        s += K[j, 4] * (0.0 * vd - Nu[j] * dr)
        out[j] = tau0[j] + Nu[j] * dr - s
    return out
