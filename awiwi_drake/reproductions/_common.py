"""Helpers shared by the chapter modules (not part of the public API)."""

from __future__ import annotations

from typing import Sequence

from awiwi_drake.analysis import Samples
from awiwi_drake.parameters.control import CONTROL_RATE_HZ

RATE = CONTROL_RATE_HZ
DT = 1.0 / RATE


def reference_schedule(steps: Sequence[tuple[float, float]], initial: float) -> Samples:
    """``initial``, then ``r_k`` from each ``t_k`` on (``steps = [(t_k, r_k), ...]``, sorted, ``t_k > 0``),
    as an input schedule for :func:`awiwi_drake.analysis.simulate`."""
    times = [0.0] + [float(t) for t, _ in steps]
    values = [float(initial)] + [float(r) for _, r in steps]
    return Samples(times, values, hold="zoh")
