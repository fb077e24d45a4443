"""Calibration tables: fitting ψ_D(θ) from turntable samples (method.md §4).

A :class:`Calibration` holds one :class:`CalibrationTable` per channel (or a
single table for every channel, ``channel: None``). Each table stores K_D,
the curve ψ_D on a regular angle grid, the unambiguous field of view (the
interval around boresight where ψ_D is strictly monotonic), the RSSI
spread seen on the turntable and the two angle terms of the σ model that
reading noise does not explain: the fit's own model error and an
environment floor measured by a check (:mod:`rfsas_hw.df.check`).
"""

from __future__ import annotations

import datetime as dt
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.interpolate import make_smoothing_spline

from rfsas_hw.df.arraycal import ArrayCalibration
from rfsas_hw.df.monopulse import Mode, balance_k_d, ratio, ratio_gradient
from rfsas_hw.df.phasecal import PhaseCalibration
from rfsas_hw.errors import CalibrationError
from rfsas_hw.rf.noise import THERMAL_K_DB, quantisation_variance_db2
from rfsas_hw.rf.synth import TurntableSamples

Array = npt.NDArray[np.floating[Any]]
FORMAT_NAME = "rfsas-calibration"
FORMAT_VERSION = 1


@dataclass(frozen=True)
class CalibrationTable:
    """ψ_D(θ) for one channel (or for all channels when ``channel`` is None)."""

    channel: int | None
    """IEEE channel this table is for; None for every channel."""
    k_d: float
    """Boresight balance constant K_D (mode-dependent, dimensionless)."""
    grid_deg: Array
    """Angle grid, degrees clockwise from boresight, strictly increasing."""
    psi: Array
    """ψ_D on the grid (dimensionless)."""
    fov_deg: tuple[float, float]
    """Unambiguous field of view, degrees (lower, upper), inside the grid."""
    noise_db: float
    """Per-chain RSSI spread of the receiver at high SNR, dB (includes quantisation)."""
    samples: int = 0
    """Turntable samples the table was fitted from."""
    residual_rms_deg: float = float("nan")
    """RMS bearing error on the fitting samples inside the FoV, degrees."""
    model_sigma_deg: float = 0.0
    """The fit's model error: RMS bearing error of the per-angle means beyond
    what their reading noise explains, degrees (0 for files that predate it)."""
    env_floor_deg: float = 0.0
    """Environment floor (multipath, unmodelled scatter) measured by
    ``calibrate --check`` on held-back data, degrees (0 until measured)."""
    level_db: Array | None = None
    """The stronger chain's smoothed reading on the grid relative to its value at
    boresight, dB (≤ a few dB inside the FoV, far below it behind the antennas);
    None for files that predate it (then taken as 0 dB)."""
    _inv_psi: Array = field(init=False, repr=False, compare=False)
    _inv_deg: Array = field(init=False, repr=False, compare=False)
    _slope: Array = field(init=False, repr=False, compare=False)
    cache: dict[str, Any] = field(init=False, repr=False, compare=False, default_factory=dict)
    """Derived lookup tables, built on first use (see :mod:`rfsas_hw.df.lut`)."""

    def __post_init__(self) -> None:
        grid = np.asarray(self.grid_deg, dtype=np.float64)
        psi = np.asarray(self.psi, dtype=np.float64)
        object.__setattr__(self, "grid_deg", grid)
        object.__setattr__(self, "psi", psi)
        lo, hi = self.fov_deg
        inside = (grid >= lo - 1e-9) & (grid <= hi + 1e-9)
        g, p = grid[inside], psi[inside]
        if len(g) < 2:
            raise CalibrationError("field of view holds fewer than two grid points")
        order = np.argsort(p)
        object.__setattr__(self, "_inv_psi", np.ascontiguousarray(p[order]))
        object.__setattr__(self, "_inv_deg", np.ascontiguousarray(g[order]))
        object.__setattr__(self, "_slope", np.gradient(psi, grid))
        if self.level_db is not None:
            level = np.asarray(self.level_db, dtype=np.float64)
            if level.shape != grid.shape or not np.all(np.isfinite(level)):
                raise CalibrationError(
                    f"level_db: {level.size} values for a grid of {grid.size}, all finite"
                )
            object.__setattr__(self, "level_db", level)
        for name in ("model_sigma_deg", "env_floor_deg"):
            value = float(getattr(self, name))
            if not (math.isfinite(value) and value >= 0.0):
                raise CalibrationError(f"{name} must be a finite number ≥ 0, got {value}")

    @property
    def extra_var_deg2(self) -> float:
        """Variance the σ model adds to every bearing of this table, deg²."""
        return self.model_sigma_deg**2 + self.env_floor_deg**2

    def angle_of(self, psi: Array) -> tuple[Array, npt.NDArray[np.bool_]]:
        """Inverse interpolation ψ → θ inside the FoV; second value marks ψ outside the curve."""
        outside = (psi < self._inv_psi[0]) | (psi > self._inv_psi[-1]) | ~np.isfinite(psi)
        return np.interp(psi, self._inv_psi, self._inv_deg), outside

    def level_at(self, angle_deg: Array) -> Array:
        """The stronger chain's reading at the given angles relative to boresight, dB
        (0 where the table has no level curve); NaN for a NaN angle (no bearing)."""
        if self.level_db is None:
            angle = np.asarray(angle_deg, dtype=np.float64)
            flat: Array = np.where(np.isnan(angle), np.nan, 0.0)
            return flat
        out: Array = np.interp(angle_deg, self.grid_deg, self.level_db)
        return out

    def slope_at(self, angle_deg: Array) -> Array:
        """dψ_D/dθ at the given angles, per degree."""
        out: Array = np.interp(angle_deg, self.grid_deg, self._slope)
        return out

    def search_angle(self, psi: Array) -> Array:
        """The published estimator: θ minimising |ψ − ψ_D(θ)| over the FoV grid (brute force).

        Slower than :meth:`angle_of` (O(n·grid)) and quantised to the grid;
        kept as the reference that the fast path is tested against.
        """
        lo, hi = self.fov_deg
        inside = (self.grid_deg >= lo - 1e-9) & (self.grid_deg <= hi + 1e-9)
        g, p = self.grid_deg[inside], self.psi[inside]
        best = np.argmin(np.abs(np.asarray(psi)[:, None] - p[None, :]), axis=1)
        out: Array = g[best]
        return out


@dataclass(frozen=True)
class Calibration:
    """A calibration file: mode, receiver facts and one table per channel."""

    mode: Mode
    """Ratio mode the tables were fitted in: ``db`` or ``linear``."""
    tables: tuple[CalibrationTable, ...]
    """Tables, at most one per channel and at most one for every channel."""
    step_db: float = 1.0
    """RSSI reporting step of the receiver, dB (1 for monitor-mode cards)."""
    noise_floor_dbm: float = -90.89
    """Power that SNR is measured against, dBm."""
    saturation_dbm: float = -10.0
    """Readings at or above this are treated as saturated, dBm."""
    antenna: Mapping[str, Any] = field(default_factory=dict)
    """Free description of the antenna pair and board (model, squint, beamwidth…)."""
    created: str = ""
    """When the calibration was made, ISO 8601 UTC."""
    phase: PhaseCalibration | None = None
    """Interferometer phase offsets of the antenna pairs (CSI receivers), or None."""
    array: ArrayCalibration | None = None
    """An array's geometry and per-element phase and gain (array DF), or None."""

    def __post_init__(self) -> None:
        seen: set[int | None] = set()
        for table in self.tables:
            if table.channel in seen:
                raise CalibrationError(f"two tables for channel {table.channel}")
            seen.add(table.channel)
        if not self.tables:
            raise CalibrationError("a calibration needs at least one table")

    def table_for(self, channel: int | None) -> CalibrationTable | None:
        """The table for ``channel``, else the all-channel table, else None."""
        fallback = None
        for table in self.tables:
            if table.channel is not None and table.channel == channel:
                return table
            if table.channel is None:
                fallback = table
        return fallback

    @property
    def channels(self) -> list[int | None]:
        """Channels with a table (None: all channels)."""
        return [t.channel for t in self.tables]


def _pooled_noise_db(uniq_inverse: npt.NDArray[np.intp], counts: Array, values: Array) -> float:
    """Per-chain spread about the per-angle means, pooled over angles and chains."""
    sums = np.zeros((len(counts), values.shape[1]))
    np.add.at(sums, uniq_inverse, values)
    means = sums / counts[:, None]
    resid = values - means[uniq_inverse]
    dof = float(np.sum(counts - 1)) * values.shape[1]
    if dof > 0:
        return float(np.sqrt(np.sum(resid**2) / dof))
    # one reading per angle: second differences of neighbours estimate the spread
    d2 = values[1:-1] - 0.5 * (values[:-2] + values[2:])
    return float(np.sqrt(np.mean(d2**2) / 1.5)) if len(d2) else 0.0


def _smooth(x: Array, y: Array, counts: npt.NDArray[np.intp], grid: Array) -> Array:
    """Smoothing spline through per-angle means (GCV strength), evaluated on ``grid``."""
    if len(x) < 5:
        return np.interp(grid, x, y)
    spline = make_smoothing_spline(x, y, w=counts.astype(np.float64))
    out: Array = spline(grid)
    return out


def _monotonic_fov(grid: Array, psi: Array) -> tuple[int, int]:
    """Index range around boresight where ψ is strictly monotonic in one direction."""
    i0 = int(np.argmin(np.abs(grid)))
    diffs = np.diff(psi)
    left = diffs[i0 - 1] if i0 > 0 else diffs[i0]
    right = diffs[i0] if i0 < len(diffs) else diffs[i0 - 1]
    sign = np.sign(left + right)
    if sign == 0:
        return i0, i0
    lo = i0
    while lo > 0 and sign * diffs[lo - 1] > 0:
        lo -= 1
    hi = i0
    while hi < len(diffs) and sign * diffs[hi] > 0:
        hi += 1
    return lo, hi


def _model_sigma_deg(
    table: CalibrationTable,
    mode: Mode,
    angles: Array,
    means: Array,
    counts: Array,
    step_db: float,
    noise_floor_dbm: float,
) -> float:
    """The fit's model error, degrees: how far the per-angle means miss the curve.

    Each angle's mean readings give a bearing; its error against the true
    angle holds the model error (the curve is smoother than the antenna, or
    the bench had multipath) plus the noise of a mean of ``count`` readings.
    The noise part, predicted by the same propagation the estimator uses, is
    subtracted in quadrature, angle by angle, and the rest averaged over the
    angles inside the FoV. 0 when noise explains everything.
    """
    est, outside = table.angle_of(ratio(means[:, 0], means[:, 1], table.k_d, mode))
    lo, hi = table.fov_deg
    inside = ~outside & (angles >= lo) & (angles <= hi)
    if not inside.any():
        return 0.0
    r1, r2, n = means[inside, 0], means[inside, 1], counts[inside]
    base = max(table.noise_db**2, quantisation_variance_db2(step_db))
    var1 = base + THERMAL_K_DB**2 * np.power(10.0, -(r1 - noise_floor_dbm) / 10.0)
    var2 = base + THERMAL_K_DB**2 * np.power(10.0, -(r2 - noise_floor_dbm) / 10.0)
    g1, g2 = ratio_gradient(r1, r2, table.k_d, mode)
    slope = np.abs(table.slope_at(est[inside]))
    noise_var = (g1 * g1 * var1 + g2 * g2 * var2) / np.maximum(slope, 1e-12) ** 2 / n
    excess = float(np.mean((est[inside] - angles[inside]) ** 2 - noise_var))
    return math.sqrt(excess) if excess > 0 else 0.0


def fit_table(
    angle_deg: Array,
    rssi1_dbm: Array,
    rssi2_dbm: Array,
    mode: Mode = "linear",
    *,
    channel: int | None = None,
    grid_step_deg: float = 0.5,
    min_fov_deg: float = 5.0,
    step_db: float = 1.0,
    noise_floor_dbm: float = -90.89,
) -> CalibrationTable:
    """Fit one table from turntable samples (angles in degrees clockwise from boresight).

    Repeated samples at one angle are averaged (in dB); each antenna's
    per-angle means are smoothed with a cubic smoothing spline whose strength
    is chosen by generalised cross-validation (weights: samples per angle), so
    the noise of the means does not break the monotonicity of ψ_D; ψ_D is
    evaluated on a regular grid; K_D balances the smoothed curves at 0°.
    The table's ``model_sigma_deg`` is the fit's model error (see
    :func:`_model_sigma_deg`); its ``env_floor_deg`` starts at 0.

    Raises:
        CalibrationError: fewer than 3 distinct angles, boresight not covered,
            or no monotonic interval of at least ``min_fov_deg`` around 0°.
    """
    angle = np.asarray(angle_deg, dtype=np.float64)
    values = np.column_stack([rssi1_dbm, rssi2_dbm]).astype(np.float64)
    ok = np.isfinite(angle) & np.all(np.isfinite(values), axis=1)
    angle, values = angle[ok], values[ok]
    uniq, inverse, counts = np.unique(np.round(angle, 6), return_inverse=True, return_counts=True)
    where = "all channels" if channel is None else f"channel {channel}"
    if len(uniq) < 3:
        raise CalibrationError(f"{where}: need samples at 3 or more angles, got {len(uniq)}")
    if not uniq[0] <= 0.0 <= uniq[-1]:
        raise CalibrationError(
            f"{where}: samples span {uniq[0]:g}°..{uniq[-1]:g}° and do not cover boresight (0°)"
        )
    sums = np.zeros((len(uniq), 2))
    np.add.at(sums, inverse, values)
    means = sums / counts[:, None]
    # The spread seen on the turntable holds the thermal term of the weaker
    # angles; the estimator adds that term back per frame from its SNR, so
    # only the receiver's own floor is stored.
    spread_db = _pooled_noise_db(inverse, counts.astype(np.float64), values)
    snr_lin = np.power(10.0, (values - noise_floor_dbm) / 10.0)
    thermal_var = float(np.mean(THERMAL_K_DB**2 / np.maximum(snr_lin, 1e-12)))
    floor_var = max(spread_db**2 - thermal_var, quantisation_variance_db2(step_db))
    noise_db = float(np.sqrt(floor_var))
    start = np.ceil(uniq[0] / grid_step_deg) * grid_step_deg
    grid = np.arange(start, uniq[-1] + 1e-9, grid_step_deg)
    r1g, r2g = (_smooth(uniq, means[:, k], counts, grid) for k in (0, 1))
    r1_0 = float(np.interp(0.0, grid, r1g))
    r2_0 = float(np.interp(0.0, grid, r2g))
    try:
        k_d = balance_k_d(r1_0, r2_0, mode)
    except ValueError as err:
        raise CalibrationError(f"{where}: cannot balance at boresight: {err}") from err
    psi = ratio(r1g, r2g, k_d, mode)
    lo, hi = _monotonic_fov(grid, psi)
    fov = (float(grid[lo]), float(grid[hi]))
    if fov[1] - fov[0] < min_fov_deg:
        raise CalibrationError(
            f"{where}: ψ_D is not monotonic around boresight "
            f"(usable field of view {fov[0]:g}°..{fov[1]:g}° is under {min_fov_deg:g}°)"
        )
    table = CalibrationTable(channel, k_d, grid, psi, fov, noise_db, samples=len(angle))
    est, outside = table.angle_of(ratio(values[:, 0], values[:, 1], k_d, mode))
    inside = ~outside & (angle >= fov[0]) & (angle <= fov[1])
    rms = (
        float(np.sqrt(np.mean((est[inside] - angle[inside]) ** 2)))
        if inside.any()
        else float("nan")
    )
    model = _model_sigma_deg(
        table, mode, uniq, means, counts.astype(np.float64), step_db, noise_floor_dbm
    )
    stronger = np.fmax(r1g, r2g)
    level = stronger - max(r1_0, r2_0)
    return CalibrationTable(
        channel, k_d, grid, psi, fov, noise_db, len(angle), rms, model, 0.0, level
    )


def fit_calibration(
    samples: TurntableSamples,
    mode: Mode = "linear",
    *,
    per_channel: bool = True,
    grid_step_deg: float = 0.5,
    min_fov_deg: float = 5.0,
    step_db: float = 1.0,
    noise_floor_dbm: float = -90.89,
    antenna: Mapping[str, Any] | None = None,
) -> Calibration:
    """Fit a calibration: one table per channel found in the samples (channel 0 = unknown).

    With ``per_channel=False``, or when no channel is recorded, one table
    serves every channel.

    Raises:
        CalibrationError: as :func:`fit_table`, naming the channel.
    """
    channels = sorted({int(c) for c in samples.channel if int(c) != 0})
    groups: list[tuple[int | None, npt.NDArray[np.bool_]]]
    if per_channel and channels:
        groups = [(ch, samples.channel == ch) for ch in channels]
    else:
        groups = [(None, np.ones(len(samples.angle_deg), dtype=bool))]
    tables = tuple(
        fit_table(
            samples.angle_deg[mask],
            samples.rssi1_dbm[mask],
            samples.rssi2_dbm[mask],
            mode,
            channel=ch,
            grid_step_deg=grid_step_deg,
            min_fov_deg=min_fov_deg,
            step_db=step_db,
            noise_floor_dbm=noise_floor_dbm,
        )
        for ch, mask in groups
    )
    created = dt.datetime.now(dt.UTC).replace(microsecond=0).isoformat().replace("+00:00", "Z")
    return Calibration(
        mode=mode,
        tables=tables,
        step_db=step_db,
        noise_floor_dbm=noise_floor_dbm,
        antenna=dict(antenna or {}),
        created=created,
    )
