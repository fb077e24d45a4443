"""How well a calibration table predicts bearings on samples it was not fitted on.

Besides the error against the predicted σ, a check splits σ into its terms
(reading noise, the fit's model error, the stored environment floor), says
which dominates, and measures the environment floor the samples call for:
the error variance that none of the modelled terms explains.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.df.calibration import Calibration
from rfsas_hw.df.estimate import DfFlag, estimate
from rfsas_hw.rf.synth import TurntableSamples

Array = npt.NDArray[np.floating[Any]]

CONSISTENT_RATIO = 1.2
"""RMS error and RMS predicted σ agree when their ratio is within [1/1.2, 1.2]."""

FLOOR_BINS = 4
"""Bins of predicted σ the environment floor is estimated in (fewer for small checks)."""

MIN_PER_BIN = 25
"""Fewest samples per bin of the floor estimate."""

TERMS = ("noise", "model", "environment")
"""Names of the σ terms, in the order :attr:`SigmaTerms.as_tuple` gives them."""


@dataclass(frozen=True, slots=True)
class SigmaTerms:
    """RMS of each σ term over the valid samples of a check, degrees."""

    noise_deg: float
    """Reading noise (measurement floor, rounding, thermal) through the curve's slope."""
    model_deg: float
    """The calibration fit's model error."""
    environment_deg: float
    """The environment floor stored in the calibration."""

    def as_tuple(self) -> tuple[float, float, float]:
        """The three terms in the order of :data:`TERMS`."""
        return (self.noise_deg, self.model_deg, self.environment_deg)

    @property
    def dominant(self) -> str:
        """Name of the largest term (``noise``, ``model`` or ``environment``)."""
        values = self.as_tuple()
        return TERMS[int(np.argmax(values))]


@dataclass(frozen=True, slots=True)
class CheckReport:
    """Bearing error of a calibration on held-back samples."""

    samples: int
    """Samples read."""
    inside_fov: int
    """Samples whose true angle lies inside the table's field of view."""
    valid: int
    """Of those, samples that gave a valid bearing."""
    rms_error_deg: float
    """RMS of (estimated − true) angle over the valid samples, degrees."""
    rms_sigma_deg: float
    """RMS of the σ the estimator predicted for the same samples, degrees."""
    max_abs_error_deg: float
    """Largest absolute error, degrees."""
    rejected: dict[str, int]
    """Samples inside the FoV without a bearing, by reason."""
    terms: SigmaTerms = SigmaTerms(math.nan, math.nan, math.nan)
    """RMS of each σ term over the valid samples."""
    measured_floor_deg: dict[int | None, float] = field(default_factory=dict)
    """Environment floor these samples call for, per table channel, degrees."""
    rms_sigma_with_floor_deg: float = math.nan
    """RMS σ with the measured floors in place of the stored ones, degrees."""
    band_ratios: tuple[float, ...] = ()
    """RMS error ÷ RMS σ in bins of equal count by predicted σ, smallest σ first.

    One overall ratio can hide a σ too small for strong frames behind one
    too large for weak ones; every band near 1 means σ is honest frame by frame.
    """

    @property
    def ratio(self) -> float:
        """RMS error divided by RMS predicted σ (1 is a perfectly honest σ)."""
        return self.rms_error_deg / self.rms_sigma_deg if self.rms_sigma_deg > 0 else float("inf")

    @property
    def ratio_with_floor(self) -> float:
        """RMS error divided by RMS σ with the measured floors (in-sample)."""
        s = self.rms_sigma_with_floor_deg
        return self.rms_error_deg / s if s > 0 else float("inf")

    @property
    def consistent(self) -> bool:
        """True when the predicted σ matches the observed error within 1.2×."""
        return 1.0 / CONSISTENT_RATIO <= self.ratio <= CONSISTENT_RATIO


def _sigma_bins(sigma2: Array) -> list[npt.NDArray[np.intp]]:
    """Indices split into up to :data:`FLOOR_BINS` bins of equal count by σ²."""
    bins = max(1, min(FLOOR_BINS, len(sigma2) // MIN_PER_BIN))
    return list(np.array_split(np.argsort(sigma2, kind="stable"), bins))


def band_ratios(error_deg: Array, sigma_deg: Array) -> tuple[float, ...]:
    """RMS error ÷ RMS σ per bin of predicted σ (see :attr:`CheckReport.band_ratios`)."""
    e2 = np.asarray(error_deg, dtype=np.float64) ** 2
    s2 = np.asarray(sigma_deg, dtype=np.float64) ** 2
    if len(e2) == 0:
        return ()
    return tuple(
        math.sqrt(float(np.mean(e2[part])) / max(float(np.mean(s2[part])), 1e-12))
        for part in _sigma_bins(s2)
    )


def environment_floor_deg(error_deg: Array, sigma_deg: Array) -> float:
    """The floor f (degrees) that makes ``σ² + f²`` match the squared errors.

    The samples are split into up to :data:`FLOOR_BINS` bins of equal count
    by predicted σ; in each, the excess ``mean(error²) − mean(σ²)`` estimates
    f². The bins are combined with weights ``n / mean(σ²)²`` (the inverse
    variance of each estimate when f is small), so the bins where σ is small
    and a floor shows most decide, and bins where σ is already conservative
    (low SNR, errors clipped at the FoV edges) do not cancel it. 0 when the
    modelled terms explain the errors; NaN without samples.
    """
    e2 = np.asarray(error_deg, dtype=np.float64) ** 2
    s2 = np.asarray(sigma_deg, dtype=np.float64) ** 2
    if len(e2) == 0:
        return math.nan
    num = den = 0.0
    for part in _sigma_bins(s2):
        ms2 = float(np.mean(s2[part]))
        weight = len(part) / max(ms2, 1e-6) ** 2
        num += weight * (float(np.mean(e2[part])) - ms2)
        den += weight
    excess = num / den
    return math.sqrt(excess) if excess > 0 else 0.0


def check_calibration(cal: Calibration, samples: TurntableSamples) -> CheckReport:
    """Estimate every sample inside its table's FoV and compare with the true angle.

    Samples outside the FoV are left out: amplitude monopulse cannot tell them
    from angles inside it (the ψ curve folds back), which is what the FoV means.
    """
    channel = samples.channel if any(t.channel is not None for t in cal.tables) else None
    result = estimate(cal, samples.rssi1_dbm, samples.rssi2_dbm, channel)
    n = len(samples.angle_deg)
    inside = np.zeros(n, dtype=bool)
    table_index = np.full(n, -1, dtype=np.intp)
    index_of = {id(t): k for k, t in enumerate(cal.tables)}
    for i, ch in enumerate(samples.channel.tolist()):
        table = cal.table_for(int(ch))
        if table is not None:
            lo, hi = table.fov_deg
            inside[i] = lo <= samples.angle_deg[i] <= hi
            table_index[i] = index_of[id(table)]
    ok = inside & result.valid
    err = (result.angle_deg[ok] - samples.angle_deg[ok]).astype(np.float64)
    sigma = result.sigma_deg[ok].astype(np.float64)
    model2 = np.array([t.model_sigma_deg**2 for t in cal.tables])[table_index[ok]]
    env2 = np.array([t.env_floor_deg**2 for t in cal.tables])[table_index[ok]]
    noise2 = np.maximum(sigma**2 - model2 - env2, 0.0)
    rejected: Counter[str] = Counter()
    for flag in DfFlag:
        if flag is DfFlag.NONE or flag.name is None:
            continue
        count = int(np.count_nonzero(inside & ((result.flags & np.uint8(flag)) != 0)))
        if count:
            rejected[flag.name.lower()] = count
    n_ok = int(ok.sum())
    if not n_ok:
        nan = math.nan
        return CheckReport(n, int(inside.sum()), 0, nan, nan, nan, dict(rejected))
    floors: dict[int | None, float] = {}
    with_floor2 = noise2 + model2
    for k, table in enumerate(cal.tables):
        mine = table_index[ok] == k
        if mine.any():
            f = environment_floor_deg(err[mine], np.sqrt(noise2[mine] + model2[mine]))
            floors[table.channel] = f
            with_floor2[mine] += f * f
        else:
            with_floor2[mine] += table.env_floor_deg**2

    def rms(values: Array) -> float:
        return float(np.sqrt(np.mean(values)))

    return CheckReport(
        samples=n,
        inside_fov=int(inside.sum()),
        valid=n_ok,
        rms_error_deg=rms(err**2),
        rms_sigma_deg=rms(sigma**2),
        max_abs_error_deg=float(np.max(np.abs(err))),
        rejected=dict(rejected),
        terms=SigmaTerms(rms(noise2), rms(model2), rms(env2)),
        measured_floor_deg=floors,
        rms_sigma_with_floor_deg=rms(with_floor2),
        band_ratios=band_ratios(err, sigma),
    )


def with_environment_floor(cal: Calibration, report: CheckReport) -> Calibration:
    """``cal`` with each table's environment floor replaced by the one ``report`` measured.

    Tables the check had no valid samples for keep their stored floor.
    """
    tables = tuple(
        dataclasses.replace(t, env_floor_deg=report.measured_floor_deg[t.channel])
        if t.channel in report.measured_floor_deg
        and math.isfinite(report.measured_floor_deg[t.channel])
        else t
        for t in cal.tables
    )
    return dataclasses.replace(cal, tables=tables)
