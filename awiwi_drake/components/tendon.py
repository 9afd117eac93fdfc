"""Tendon elasticity, springs in series and the joint stiffness of a tendon drive (thesis ch. 4, section 5.1,
(5.12), (8.1)).

The guide friction laws (4.1) are in :mod:`awiwi_drake.components.friction`.
"""

from __future__ import annotations

import numpy as np

from awiwi_drake._math import is_float
from awiwi_drake.parameters.components import TendonParams

__all__ = ["tendon_stiffness", "series_stiffness", "joint_stiffness"]


def tendon_stiffness(p: TendonParams) -> float:
    """Axial stiffness of the tendon ``k_t = E S / l0`` [N/m] (section 5.1)."""
    return p.youngs_modulus * p.cross_section / p.rest_length


def joint_stiffness(P: np.ndarray, k_t: np.ndarray, f: np.ndarray, hessian: np.ndarray | None = None) -> np.ndarray:
    """Joint stiffness ``K_q = P^T diag(k_t) P + sum_i f_i d^2 h_i/dq^2`` (5.12), (7.1).

    ``hessian[i, j, k] = d P_ij / d q_k`` (m x n x n), omitted for a constant coupling.  Leading axes
    (several fingers at once) broadcast.
    """
    K = np.swapaxes(P, -1, -2) @ (k_t[..., :, None] * P)
    if hessian is not None:
        K = K + np.einsum("...i,...ijk->...jk", f, hessian)
    return K


def series_stiffness(k_a, k_b):
    """Two stiffnesses in series (8.1): ``(k_a^-1 + k_b^-1)^-1``.

    Scalars and arrays combine element-wise as ``k_a k_b / (k_a + k_b)`` (generic in the scalar type; a slack
    element, ``k = 0``, gives 0; float inputs must be >= 0 with a positive sum).  Two square matrices (e.g. a
    controller impedance and the mechanical joint stiffness of (8.1)) combine as ``K_a (K_a + K_b)^-1 K_b``.
    """
    a, b = np.asarray(k_a), np.asarray(k_b)
    if a.ndim == 2 or b.ndim == 2:
        a, b = np.atleast_2d(a).astype(float), np.atleast_2d(b).astype(float)
        if a.shape != b.shape or a.shape[0] != a.shape[1]:
            raise ValueError(f"series_stiffness: matrices must be square and of one shape, got {a.shape} and {b.shape}")
        return a @ np.linalg.solve(a + b, b)
    if is_float(a) and is_float(b):
        if np.any(a < 0) or np.any(b < 0) or np.any(a + b <= 0):
            raise ValueError("series_stiffness: stiffnesses must be >= 0 with a positive sum, "
                             f"got k_a = {k_a}, k_b = {k_b}")
    out = a * b / (a + b)
    return out[()] if isinstance(out, np.ndarray) and out.shape == () else out
