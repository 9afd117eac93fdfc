"""Helpers shared by the chapter modules (not part of the public API)."""

from __future__ import annotations

from awiwi_drake.parameters.control import CONTROL_RATE_HZ

RATE = CONTROL_RATE_HZ
DT = 1.0 / RATE
