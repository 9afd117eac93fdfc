"""Thesis section 5.5: the fifth finger's hematometacarpal (HMC) four-bar and the revolute that replaces it.

The thesis designs the HMC joint "as a four bars linkage mechanism" to "mimic the human metacarpal
motion and especially [provide] a locking motion towards the palm center when the joint limits are
reached", and prints no dimensions.  The package models it as one revolute axis
(``FifthFingerParams.hmc_axis_tilt``, ``hmc_offset``): the four-bar's *instantaneous* axis at the
reference pose.  That is exact to first order; :func:`hmc_revolute_error` measures the second-order
error on representative four-bars (chosen dimensions: none are printed).

Four-bar (in the plane normal to the HMC axis): symmetric, both rockers on lines through the
instantaneous centre (IC, the revolute's axis) at angles +-``alpha`` from the metacarpal's axis,
ground pivots at ``r_ground`` and metacarpal pivots at ``r_coupler`` from the IC; the MCP base point
lies ``distance`` (the package's ``hmc_offset``, 30 mm) from the IC.  For a metacarpal rotation
``phi`` the error is the distance between the MCP base point moved by the four-bar and by the
revolute about the initial IC.  The revolute cannot show the 'locking' at the joint limits at all
(that is a property of the four-bar near its singular pose, not of its first-order motion).
"""

from __future__ import annotations

import numpy as np

__all__ = ["hmc_revolute_error"]


def hmc_revolute_error(phi, *, alpha: float = np.radians(20.0), r_ground: float = 0.010,
                       r_coupler: float = 0.022, distance: float = 0.030) -> np.ndarray:
    """Position error [m] of the MCP base point, four-bar vs revolute, at metacarpal rotations ``phi`` [rad]."""
    from scipy.optimize import fsolve
    phi = np.atleast_1d(np.asarray(phi, dtype=float))
    if not (0.0 <= r_ground < r_coupler and 0.0 < alpha < np.pi / 2 and distance > 0.0):
        raise ValueError("hmc_revolute_error: need 0 <= r_ground < r_coupler, 0 < alpha < pi/2, distance > 0 "
                         f"(got r_ground={r_ground}, r_coupler={r_coupler}, alpha={alpha}, distance={distance})")
    u1, u2 = np.array([-np.sin(alpha), np.cos(alpha)]), np.array([np.sin(alpha), np.cos(alpha)])
    G1, G2, C1, C2 = r_ground * u1, r_ground * u2, r_coupler * u1, r_coupler * u2
    P = np.array([0.0, distance])
    L, c = np.linalg.norm(C1 - G1), np.linalg.norm(C2 - C1)
    ex = (C2 - C1) / c
    ey = np.array([-ex[1], ex[0]])
    p_local = np.array([(P - C1) @ ex, (P - C1) @ ey])
    theta0 = np.arctan2(ex[1], ex[0])
    out = []
    for f in phi:
        def closure(t):
            a = G1 + L * np.array([np.cos(t[0]), np.sin(t[0])])
            b = G2 + L * np.array([np.cos(t[1]), np.sin(t[1])])
            d = b - a
            return [np.linalg.norm(d) - c, np.arctan2(d[1], d[0]) - (theta0 + f)]
        t0 = [np.arctan2(*(C1 - G1)[::-1]), np.arctan2(*(C2 - G2)[::-1])]
        t, _, ok, msg = fsolve(closure, t0, xtol=1e-13, full_output=True)
        if ok != 1 and np.max(np.abs(closure(t))) > 1e-10:
            raise ValueError(f"hmc_revolute_error: the four-bar cannot reach phi = {f:.4g} rad ({msg.strip()})")
        a = G1 + L * np.array([np.cos(t[0]), np.sin(t[0])])
        R = np.array([[np.cos(f), -np.sin(f)], [np.sin(f), np.cos(f)]])
        out.append(np.linalg.norm(a + R @ (p_local[0] * ex + p_local[1] * ey) - R @ P))
    return np.array(out)
