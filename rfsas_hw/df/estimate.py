"""Bearings from RSSI pairs: vectorised inverse lookup of ψ_D with a σ per bearing.

For each frame: ψ from both readings, θ from the table's monotonic FoV by
inverse interpolation, and

    σ_θ = σ_ψ / |dψ_D/dθ(θ)|,  σ_ψ² = (∂ψ/∂RSSI₁)²·σ₁² + (∂ψ/∂RSSI₂)²·σ₂²,
    σ_i² = max(noise_db², step²/12) + (10/ln10)² / SNR_i

where ``noise_db`` is the spread measured on the turntable (which already
holds the 1 dB quantisation of the card; the ``step²/12`` floor covers a
table fitted from smoothed or unquantised data) and the last term grows the
spread at low SNR (:mod:`rfsas_hw.rf.noise`). Two terms that reading
noise does not cover are added in quadrature, per table:

    σ² = σ_θ² + σ_model² + σ_env²

``σ_model`` is the calibration fit's own model error (how far its per-angle
means miss the fitted curve beyond their noise) and ``σ_env`` the
environment floor (multipath, scatter) that ``calibrate --check`` measures
on held-back data and stores with the table. Both are 0 in files that
predate them, which keeps their σ unchanged.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.df.calibration import Calibration, CalibrationTable
from rfsas_hw.df.fovrule import EDGE_SIGMAS, near_edge
from rfsas_hw.df.lut import lut_for
from rfsas_hw.df.monopulse import ratio, ratio_gradient
from rfsas_hw.rf.noise import THERMAL_K_DB, quantisation_variance_db2

Array = npt.NDArray[np.floating[Any]]
_LN10_10 = math.log(10.0) / 10.0


class DfFlag(enum.IntFlag):
    """Why a bearing is not valid (0 = valid)."""

    NONE = 0
    MISSING_CHAIN = 0x01
    """An antenna reported no value (NaN)."""
    SATURATED = 0x02
    """A reading at or above the calibration's saturation level."""
    OUTSIDE_FOV = 0x04
    """ψ falls outside the monotonic part of ψ_D."""
    NO_TABLE = 0x08
    """No calibration table for the frame's channel."""
    LOW_SNR = 0x10
    """The stronger antenna is below the minimum SNR."""
    AMBIGUOUS = 0x20
    """Interferometer only: more than one phase branch fits and nothing decides."""
    MAY_BE_OUTSIDE = 0x40
    """The emitter may lie outside the FoV: the bearing's ±k·σ reaches past an edge, or
    both chains are weak against the emitter's boresight level (:mod:`rfsas_hw.df.fovrule`)."""


@dataclass(frozen=True, slots=True)
class DfResult:
    """Per-frame direction-finding results (arrays of one length)."""

    angle_deg: Array
    """Angle from boresight, degrees clockwise; NaN where invalid."""
    sigma_deg: Array
    """One-sigma angle error, degrees; NaN where invalid."""
    snr_db: Array
    """SNR of the stronger antenna, dB."""
    flags: npt.NDArray[np.uint8]
    """:class:`DfFlag` bits; 0 where the bearing is valid."""

    @property
    def valid(self) -> npt.NDArray[np.bool_]:
        """True where the bearing can be used."""
        out: npt.NDArray[np.bool_] = self.flags == 0
        return out


def _estimate_table(
    cal: Calibration, table: CalibrationTable, r1: Array, r2: Array, edge_sigmas: float
) -> tuple[Array, Array, npt.NDArray[np.uint8]]:
    lut = lut_for(table, cal.mode)
    base_var = np.float32(max(table.noise_db**2, quantisation_variance_db2(cal.step_db)))
    # (10/ln10)²/SNR = K²·exp(−(r − floor)·ln10/10)
    thermal = np.float32(THERMAL_K_DB**2 * math.exp(cal.noise_floor_dbm * _LN10_10))
    var1 = np.exp(r1 * np.float32(-_LN10_10))
    var1 *= thermal
    var1 += base_var
    var2 = np.exp(r2 * np.float32(-_LN10_10))
    var2 *= thermal
    var2 += base_var
    if cal.mode == "linear":
        # angle and |∂ψ/∂RSSI|/|dψ_D/dθ| are functions of the difference alone
        angle, factor, outside = lut(r1 - r2)
        var1 += var2
        sigma = np.sqrt(var1)
        sigma *= factor
    else:
        psi = ratio(r1, r2, table.k_d, cal.mode)
        angle, inv_slope, outside = lut(psi)
        g1, g2 = ratio_gradient(r1, r2, table.k_d, cal.mode)
        sigma = np.sqrt(g1 * g1 * var1 + g2 * g2 * var2) * inv_slope
    extra = table.extra_var_deg2
    if extra > 0.0:
        sigma *= sigma
        sigma += np.float32(extra)
        np.sqrt(sigma, out=sigma)
    flags = outside.view(np.uint8) * np.uint8(DfFlag.OUTSIDE_FOV)
    if edge_sigmas > 0.0:
        edge = near_edge(angle, sigma, table.fov_deg, edge_sigmas) & ~outside
        flags |= edge.view(np.uint8) * np.uint8(DfFlag.MAY_BE_OUTSIDE)
    return angle, sigma, flags


def estimate(
    cal: Calibration,
    rssi1_dbm: npt.ArrayLike,
    rssi2_dbm: npt.ArrayLike,
    channel: npt.ArrayLike | None = None,
    *,
    min_snr_db: float | None = None,
    edge_sigmas: float = EDGE_SIGMAS,
) -> DfResult:
    """Angle, σ and validity for RSSI pairs (dBm arrays; ``channel`` per frame or None).

    Frames whose channel has no table use the calibration's all-channel
    table, or are flagged ``NO_TABLE``. A bearing whose ``± edge_sigmas·σ``
    reaches past the table's FoV is flagged ``MAY_BE_OUTSIDE`` (the edge rule
    of :mod:`rfsas_hw.df.fovrule`; 0 turns it off).
    """
    # float32 halves memory traffic; readings are whole or half dB anyway
    r1 = np.asarray(rssi1_dbm, dtype=np.float32)
    r2 = np.asarray(rssi2_dbm, dtype=np.float32)
    n = len(r1)
    peak = np.fmax(r1, r2)
    missing = ~np.isfinite(r1 + r2)
    # bool arrays viewed as 0/1 bytes: flag words without masked writes
    flags = missing.view(np.uint8) * np.uint8(DfFlag.MISSING_CHAIN)
    flags |= (peak >= cal.saturation_dbm).view(np.uint8) * np.uint8(DfFlag.SATURATED)
    snr = peak - cal.noise_floor_dbm
    if min_snr_db is not None:
        low = ~(snr >= min_snr_db) & ~missing
        flags |= low.view(np.uint8) * np.uint8(DfFlag.LOW_SNR)
    if channel is None or (len(cal.tables) == 1 and cal.tables[0].channel is None):
        groups: list[tuple[int | None, npt.NDArray[np.bool_] | None]] = [(None, None)]
    else:
        ch = np.asarray(channel)
        if n and ch.min() == ch.max():  # the usual case: one channel, no sort
            groups = [(int(ch[0]), None)]
        else:
            groups = [(int(c), ch == c) for c in np.unique(ch)]
    angle = sigma = None
    for c, mask in groups:
        table = cal.table_for(c)
        if mask is None:  # every frame uses this table: no gathers or scatters
            if table is None:
                flags |= np.uint8(DfFlag.NO_TABLE)
            else:
                angle, sigma, fov_flags = _estimate_table(cal, table, r1, r2, edge_sigmas)
                flags |= fov_flags
            continue
        if angle is None or sigma is None:
            angle, sigma = np.full(n, np.nan, np.float32), np.full(n, np.nan, np.float32)
        if table is None:
            flags[mask] |= np.uint8(DfFlag.NO_TABLE)
            continue
        a, s, fov_flags = _estimate_table(cal, table, r1[mask], r2[mask], edge_sigmas)
        angle[mask] = a
        sigma[mask] = s
        flags[mask] |= fov_flags
    if angle is None or sigma is None:
        angle, sigma = np.full(n, np.nan, np.float32), np.full(n, np.nan, np.float32)
    bad = flags != 0
    np.putmask(angle, bad, np.nan)
    np.putmask(sigma, bad, np.nan)
    return DfResult(angle, sigma, snr, flags)
