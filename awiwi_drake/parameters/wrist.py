"""Wrist of the Awiwi hand (thesis ch. 6): geometry and tendon offsets.

Table 6.1 gives the wrist box (a, b, c); Table 6.2, transcribed row by row, the point each of the 38
tendons passes in the forearm frame 0 and in the palm frame ABC (two layers of 19: rows 1-19 at forearm
z = 0.008 m / palm z = +0.010 m, rows 20-38 at 0.028 m / -0.010 m; printed to 1 mm, so lengths built from
them carry ~+-0.5 mm of rounding).  The linkage lengths are not printed; they are derived from a, b, c by
the box construction of :mod:`awiwi_drake.hand.wrist` (read-only properties here).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .base import Parameters, param

__all__ = ["WristParams", "WRIST_NUM_TENDONS", "TABLE_6_2_FOREARM", "TABLE_6_2_PALM"]

WRIST_NUM_TENDONS = 38

#: Table 6.2, forearm column: point of tendon i in the forearm frame 0 [m], rows 1..38.
TABLE_6_2_FOREARM = (
    0.004, 0.007, 0.008,  # 1
    0.004, 0.008, 0.008,  # 2
    0.004, 0.010, 0.008,  # 3
    0.004, 0.011, 0.008,  # 4
    0.004, 0.013, 0.008,  # 5
    0.004, 0.015, 0.008,  # 6
    0.004, 0.016, 0.008,  # 7
    0.004, 0.018, 0.008,  # 8
    0.004, 0.019, 0.008,  # 9
    0.004, 0.021, 0.008,  # 10
    0.004, 0.023, 0.008,  # 11
    0.004, 0.024, 0.008,  # 12
    0.004, 0.026, 0.008,  # 13
    0.004, 0.027, 0.008,  # 14
    0.004, 0.029, 0.008,  # 15
    0.004, 0.031, 0.008,  # 16
    0.004, 0.032, 0.008,  # 17
    0.004, 0.034, 0.008,  # 18
    0.004, 0.035, 0.008,  # 19
    0.004, 0.006, 0.028,  # 20
    0.004, 0.007, 0.028,  # 21
    0.004, 0.009, 0.028,  # 22
    0.004, 0.011, 0.028,  # 23
    0.004, 0.012, 0.028,  # 24
    0.004, 0.014, 0.028,  # 25
    0.004, 0.015, 0.028,  # 26
    0.004, 0.017, 0.028,  # 27
    0.004, 0.019, 0.028,  # 28
    0.004, 0.020, 0.028,  # 29
    0.004, 0.022, 0.028,  # 30
    0.004, 0.023, 0.028,  # 31
    0.004, 0.025, 0.028,  # 32
    0.004, 0.027, 0.028,  # 33
    0.004, 0.028, 0.028,  # 34
    0.004, 0.030, 0.028,  # 35
    0.004, 0.031, 0.028,  # 36
    0.004, 0.033, 0.028,  # 37
    0.004, 0.035, 0.028,  # 38
)

#: Table 6.2, palm column: point of tendon i in the palm frame ABC [m], rows 1..38.
TABLE_6_2_PALM = (
    -0.004, -0.011, 0.010,  # 1
    -0.004, -0.010, 0.010,  # 2
    -0.004, -0.008, 0.010,  # 3
    -0.004, -0.006, 0.010,  # 4
    -0.004, -0.005, 0.010,  # 5
    -0.004, -0.003, 0.010,  # 6
    -0.004, -0.002, 0.010,  # 7
    -0.004, 0.000, 0.010,  # 8
    -0.004, 0.002, 0.010,  # 9
    -0.004, 0.003, 0.010,  # 10
    -0.004, 0.005, 0.010,  # 11
    -0.004, 0.006, 0.010,  # 12
    -0.004, 0.008, 0.010,  # 13
    -0.004, 0.010, 0.010,  # 14
    -0.004, 0.011, 0.010,  # 15
    -0.004, 0.013, 0.010,  # 16
    -0.004, 0.014, 0.010,  # 17
    -0.004, 0.016, 0.010,  # 18
    -0.004, 0.018, 0.010,  # 19
    -0.004, -0.013, -0.010,  # 20
    -0.004, -0.011, -0.010,  # 21
    -0.004, -0.010, -0.010,  # 22
    -0.004, -0.008, -0.010,  # 23
    -0.004, -0.006, -0.010,  # 24
    -0.004, -0.005, -0.010,  # 25
    -0.004, -0.003, -0.010,  # 26
    -0.004, -0.002, -0.010,  # 27
    -0.004, 0.000, -0.010,  # 28
    -0.004, 0.002, -0.010,  # 29
    -0.004, 0.003, -0.010,  # 30
    -0.004, 0.005, -0.010,  # 31
    -0.004, 0.006, -0.010,  # 32
    -0.004, 0.008, -0.010,  # 33
    -0.004, 0.010, -0.010,  # 34
    -0.004, 0.011, -0.010,  # 35
    -0.004, 0.013, -0.010,  # 36
    -0.004, 0.014, -0.010,  # 37
    -0.004, 0.016, -0.010,  # 38
)


@dataclass(frozen=True)
class WristParams(Parameters):
    """Geometry of the wrist (double inverted parallelogram) and its 38 tendon points.

    Frames as in :mod:`awiwi_drake.hand.wrist` (forearm frame 0 at a corner of the wrist box; the palm
    frame ABC from the palm points).  Derived lengths: ``crank_length`` R_BB0 = R_CC0 =
    sqrt(a^2 + b^2 + c^2), ``coupler_length`` D_BC = c, ``palm_radius`` R_AA0 = |AM| = b, ``link_length``
    |AA0| = sqrt(a^2 + b^2).
    """

    length: float = param(0.050, unit="m", low=0.0, low_inclusive=False,
                          source="Table 6.1 (a, wrist length)",
                          doc="distance forearm face to palm face in the neutral wrist")
    width: float = param(0.042, unit="m", low=0.0, low_inclusive=False,
                         source="Table 6.1 (b, wrist width)", doc="wrist width (y)")
    thickness: float = param(0.036, unit="m", low=0.0, low_inclusive=False,
                             source="Table 6.1 (c, wrist thickness)", doc="wrist thickness (z)")
    forearm_offsets: tuple = param(TABLE_6_2_FOREARM, unit="m", vector=True, low=-0.2, high=0.2,
                                   source="Table 6.2 (forearm column), rows 1-38, flattened [x, y, z]",
                                   doc="tendon points in the forearm frame 0, 38 x 3 flattened")
    palm_offsets: tuple = param(TABLE_6_2_PALM, unit="m", vector=True, low=-0.2, high=0.2,
                                source="Table 6.2 (palm column), rows 1-38, flattened [x, y, z]",
                                doc="tendon points in the palm frame ABC, 38 x 3 flattened")

    def _validate(self) -> None:
        for name in ("forearm_offsets", "palm_offsets"):
            n = len(getattr(self, name))
            if n % 3 != 0 or n == 0:
                raise ValueError(f"WristParams.{name} has {n} values: must be 3 per tendon (x, y, z)")
        nf, npalm = len(self.forearm_offsets) // 3, len(self.palm_offsets) // 3
        if nf != npalm:
            raise ValueError(f"WristParams.forearm_offsets has {nf} tendons but "
                             f"WristParams.palm_offsets has {npalm}: they must match row by row")

    # --- derived quantities -------------------------------------------------
    @property
    def num_tendons(self) -> int:
        """Number of tendons through the wrist (38 for Table 6.2)."""
        return len(self.forearm_offsets) // 3

    @property
    def forearm_offset_array(self) -> np.ndarray:
        """Tendon points in the forearm frame 0, shape (num_tendons, 3) [m]."""
        return np.asarray(self.forearm_offsets, dtype=float).reshape(-1, 3)

    @property
    def palm_offset_array(self) -> np.ndarray:
        """Tendon points in the palm frame ABC, shape (num_tendons, 3) [m]."""
        return np.asarray(self.palm_offsets, dtype=float).reshape(-1, 3)

    @property
    def diagonal_length(self) -> float:
        """sqrt(a^2 + b^2): distance of the coupler BC from the ground B0C0 in the BC plane [m]."""
        return math.hypot(self.length, self.width)

    @property
    def crank_length(self) -> float:
        """R_BB0 = R_CC0 = sqrt(a^2 + b^2 + c^2): the crossed cranks (box space diagonals) [m]."""
        return math.sqrt(self.length ** 2 + self.width ** 2 + self.thickness ** 2)

    @property
    def coupler_length(self) -> float:
        """D_BC = c: palm edge BC (equal to the forearm edge B0C0, inverted parallelogram) [m]."""
        return self.thickness

    @property
    def palm_radius(self) -> float:
        """R_AA0 = |AM| = b: radius of the circle of A around M in (6.5) [m]."""
        return self.width

    @property
    def link_length(self) -> float:
        """|AA0| = sqrt(a^2 + b^2): the distance constraint (6.7) [m]."""
        return math.hypot(self.length, self.width)

    @property
    def palm_edge_length(self) -> float:
        """|AB| = |AC| = sqrt(b^2 + c^2/4) [m]."""
        return math.hypot(self.width, 0.5 * self.thickness)
