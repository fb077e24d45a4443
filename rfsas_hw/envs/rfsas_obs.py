"""The RF-SAS picture as a fixed-size observation: one row per tracked emitter.

:func:`encode` turns the bridge's assessments into a ``float32`` array of
shape ``(max_emitters, len(FEATURES))``. Positions and covariances are in the
ego's frame (``forward`` along its heading, ``left`` to its left), so a
policy sees the same numbers wherever the scene is on the map.

Columns (:data:`FEATURES`), every one in the bounds of :func:`rfsas_space`:

====  ===============  =================================================  ===========
col   name             meaning                                            range
====  ===============  =================================================  ===========
0     ``present``      1 for a tracked emitter, 0 for a padding row       {0, 1}
1     ``forward``      metres ahead of the ego's centre / ``range_m``      [-1, 1]
2     ``left``         metres to the ego's left / ``range_m``              [-1, 1]
3     ``cov_ff``       forward variance, m² / ``cov_m2``                   [0, 1]
4     ``cov_fl``       forward-left covariance, m² / ``cov_m2``            [-1, 1]
5     ``cov_ll``       left variance, m² / ``cov_m2``                      [0, 1]
6     ``p_collision``  probability that the boxes overlap                 [0, 1]
7     ``risk``         ``p_collision × fatality risk``                    [0, 1]
8     ``advisory``     none 0, clear 1/3, caution 2/3, brake 1            [0, 1]
9     ``fix_ok``       1 when the latest fix passed every check           {0, 1}
10    ``age``          seconds since the newest bearing / ``age_s``        [0, 1]
====  ===============  =================================================  ===========

Values beyond a scale are clipped to it. Rows are sorted by advisory
(brake first), then risk (highest first), then distance (nearest first);
the rest are zero (padding). Emitters beyond ``max_emitters`` are dropped
(the least urgent ones).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rfsas_hw.bridges.bridge import Entity
from rfsas_hw.records import Assessment

ObsArray = npt.NDArray[np.float32]

FEATURES = (
    "present",
    "forward",
    "left",
    "cov_ff",
    "cov_fl",
    "cov_ll",
    "p_collision",
    "risk",
    "advisory",
    "fix_ok",
    "age",
)
"""Column names of an encoded row (see the module docstring)."""
ADVISORY_LEVEL = {"none": 0.0, "clear": 1.0 / 3.0, "caution": 2.0 / 3.0, "brake": 1.0}
"""Encoded value of each advisory."""

__all__ = ["ADVISORY_LEVEL", "FEATURES", "ObsScales", "encode", "rfsas_space_bounds"]


@dataclass(frozen=True)
class ObsScales:
    """Scales that bring the physical values into the space's bounds."""

    range_m: float = 100.0
    """Distance that maps to 1, metres."""
    cov_m2: float = 100.0
    """Variance that maps to 1, m² (a 10 m standard deviation)."""
    age_s: float = 5.0
    """Age that maps to 1, seconds."""

    def __post_init__(self) -> None:
        if not (self.range_m > 0 and self.cov_m2 > 0 and self.age_s > 0):
            raise ValueError("observation scales must be positive")


def rfsas_space_bounds(max_emitters: int) -> tuple[ObsArray, ObsArray]:
    """Lower and upper bounds of the encoded array, each ``(max_emitters, len(FEATURES))``."""
    lo = np.zeros((max_emitters, len(FEATURES)), np.float32)
    hi = np.ones_like(lo)
    for col in ("forward", "left", "cov_fl"):
        lo[:, FEATURES.index(col)] = -1.0
    return lo, hi


def _finite(value: float, default: float = 0.0) -> float:
    return value if math.isfinite(value) else default


def encode(
    assessments: Sequence[Assessment],
    ego: Entity,
    max_emitters: int,
    scales: ObsScales | None = None,
) -> ObsArray:
    """The rows of the observation (see the module docstring).

    Args:
        assessments: the bridge's assessments at this step.
        ego: the ego vehicle (rfsas frame).
        max_emitters: rows in the output.
        scales: normalisation scales (default :class:`ObsScales`).
    """
    sc = scales or ObsScales()
    out = np.zeros((max_emitters, len(FEATURES)), np.float32)
    h = math.radians(ego.heading_deg)
    rot = np.array([[math.sin(h), math.cos(h)], [-math.cos(h), math.sin(h)]])
    rows: list[tuple[tuple[float, float, float], list[float]]] = []
    for a in assessments:
        if not (math.isfinite(a.x_m) and math.isfinite(a.y_m)):
            continue
        rel = rot @ np.array([a.x_m - ego.x_m, a.y_m - ego.y_m])
        cov = rot @ a.covariance @ rot.T
        cov = np.where(np.isfinite(cov), cov, sc.cov_m2)
        level = ADVISORY_LEVEL.get(a.advisory, 0.0)
        risk = _finite(a.risk)
        dist = float(np.hypot(*rel))
        row = [
            1.0,
            float(rel[0]) / sc.range_m,
            float(rel[1]) / sc.range_m,
            float(cov[0, 0]) / sc.cov_m2,
            float(cov[0, 1]) / sc.cov_m2,
            float(cov[1, 1]) / sc.cov_m2,
            _finite(a.p_collision),
            risk,
            level,
            1.0 if a.fix_ok else 0.0,
            _finite(a.age_s, sc.age_s) / sc.age_s,
        ]
        rows.append(((-level, -risk, dist), row))
    rows.sort(key=lambda r: r[0])
    lo, hi = rfsas_space_bounds(1)
    for i, (_, row) in enumerate(rows[:max_emitters]):
        out[i] = np.clip(np.asarray(row, np.float32), lo[0], hi[0])
    return out
