"""Helpers shared by the chapter modules (not part of the public API)."""

from __future__ import annotations

from typing import Sequence

from awiwi_drake.parameters.control import CONTROL_RATE_HZ

RATE = CONTROL_RATE_HZ
DT = 1.0 / RATE


def reference_schedule(steps: Sequence[tuple[float, float]], initial: float):
    """``r(t)``: ``initial``, then ``r_k`` from each ``t_k`` on (``steps = [(t_k, r_k), ...]``, sorted)."""
    def ref(t):
        r = initial
        for t_k, r_k in steps:
            if t >= t_k:
                r = r_k
        return r
    return ref
