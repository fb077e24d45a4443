"""Uniform lookup tables: the estimator's O(1)-per-frame inverse of ψ_D.

A binary search over the calibration grid (``numpy.interp``) costs
O(log grid) per frame; a table uniform in its input costs one multiply, one
floor and two gathers. What the table is indexed by depends on the mode:

- ``linear``: ψ depends only on Δ = RSSI₁ − RSSI₂, so the table is indexed
  by Δ (dB) and the tanh is folded into it; its second column is
  ``|∂ψ/∂RSSI| / |dψ_D/dθ|`` (degrees per dB), so σ_θ is that times
  ``√(σ₁² + σ₂²)``.
- ``db``: ψ depends on both readings; the table is indexed by ψ and its
  second column is ``1/|dψ_D/dθ|`` (degrees per unit ψ).

Inside the FoV, where ψ_D has a usable slope, the tables agree with exact
inverse interpolation to well under 0.01° (tested).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.df.calibration import CalibrationTable
from rfsas_hw.df.monopulse import Mode

LUT_SIZE = 16384
_LN10_10 = math.log(10.0) / 10.0
Array = npt.NDArray[np.floating[Any]]


@dataclass(frozen=True, slots=True)
class UniformLut:
    """Two functions of one input, tabulated on a uniform grid, linear in between."""

    x0: float
    """Input at the first entry."""
    scale: float
    """Entries per unit of input."""
    angle: npt.NDArray[np.float32]
    angle_step: npt.NDArray[np.float32]
    factor: npt.NDArray[np.float32]
    factor_step: npt.NDArray[np.float32]

    @classmethod
    def tabulate(cls, x: Array, angle: Array, factor: Array) -> UniformLut:
        """Build from samples on a uniform, increasing ``x``."""
        f32 = np.float32
        return cls(
            x0=float(x[0]),
            scale=(len(x) - 1) / float(x[-1] - x[0]),
            angle=angle.astype(f32),
            angle_step=np.diff(angle, append=angle[-1]).astype(f32),
            factor=factor.astype(f32),
            factor_step=np.diff(factor, append=factor[-1]).astype(f32),
        )

    def __call__(self, x: Array) -> tuple[Array, Array, npt.NDArray[np.bool_]]:
        """(angle in degrees, factor, outside-the-table mask) for each input."""
        last = len(self.angle) - 1
        u = x - np.float32(self.x0)
        u *= np.float32(self.scale)
        outside = ~((u >= 0.0) & (u <= np.float32(last)))
        cell = np.floor(u)
        frac = u - cell  # in [0, 1) for every finite input, inside the table or not
        if outside.any():
            with np.errstate(invalid="ignore"):  # NaN inputs (flagged upstream) cast to garbage
                i = cell.astype(np.int32)
        else:  # every input inside the table: finite, nothing to silence
            i = cell.astype(np.int32)
        np.maximum(i, 0, out=i)
        np.minimum(i, last - 1, out=i)
        angle = self.angle[i]
        angle += frac * self.angle_step[i]
        factor = self.factor[i]
        factor += frac * self.factor_step[i]
        return angle, factor, outside


def lut_for(table: CalibrationTable, mode: Mode) -> UniformLut:
    """The lookup table of ``table`` in ``mode``, built once and cached on the table."""
    lut = table.cache.get(mode)
    if lut is None:
        lut = _build(table, mode)
        table.cache[mode] = lut
    assert isinstance(lut, UniformLut)
    return lut


def _build(table: CalibrationTable, mode: Mode) -> UniformLut:
    psi_lo, psi_hi = float(table._inv_psi[0]), float(table._inv_psi[-1])
    if mode == "linear":
        # ψ = tanh(a·Δ − b): invert the FoV's ψ range to a Δ range
        a, b = 0.5 * _LN10_10, 0.5 * math.log(table.k_d)
        d_lo, d_hi = (math.atanh(psi_lo) + b) / a, (math.atanh(psi_hi) + b) / a
        x = np.linspace(d_lo, d_hi, LUT_SIZE)
        psi = np.clip(np.tanh(a * x - b), psi_lo, psi_hi)
        dpsi_dr = a * (1.0 - psi**2)
    else:
        x = np.linspace(psi_lo, psi_hi, LUT_SIZE)
        psi = x
        dpsi_dr = np.ones_like(x)
    angle = np.interp(psi, table._inv_psi, table._inv_deg)
    slope = np.abs(table.slope_at(angle))
    return UniformLut.tabulate(x, angle, dpsi_dr / np.maximum(slope, 1e-12))
