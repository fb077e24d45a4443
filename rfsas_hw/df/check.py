"""How well a calibration table predicts bearings on samples it was not fitted on.

Every sample is scored, wherever its true angle lies: a sample from outside
the field of view that still produced a bearing is exactly the bearing that
misleads a backend, so it counts in the errors, the σ ratio and the share of
*confident-wrong* bearings (error beyond 3σ), and the verdict uses them.
Bearings go through the same field-of-view rules as in the sensor
(:mod:`rfsas_hw.df.fovrule`); the level rule's reference is the brightest
boresight-equivalent level of the run (a turntable run holds one emitter at
one range). A check also says when there is nothing to check, when its
floor rests on too few samples, and when one constant angle would have
beaten the bearings.

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
from rfsas_hw.df.estimate import DfFlag, DfResult, estimate
from rfsas_hw.df.fovguard import boresight_levels, fold_drops, refuse_weak
from rfsas_hw.df.fovrule import fold_margin_db
from rfsas_hw.rf.synth import TurntableSamples

Array = npt.NDArray[np.floating[Any]]

CONSISTENT_RATIO = 1.2
"""RMS error and RMS predicted σ agree when their ratio is within [1/1.2, 1.2]."""

FLOOR_BINS = 4
"""Bins of predicted σ the environment floor is estimated in (fewer for small checks)."""

MIN_PER_BIN = 25
"""Fewest samples per bin of the floor estimate."""

CONFIDENT_WRONG_SIGMAS = 3.0
"""A bearing whose error exceeds this many σ is confident-wrong."""

CONFIDENT_WRONG_MAX = 0.05
"""Most confident-wrong bearings a consistent check may hold (a share of its bearings)."""

MIN_FLOOR_SAMPLES = 100
"""Fewer bearings than this make a measured environment floor unreliable: warned."""

REFERENCE_PERCENTILE = 95.0
"""Percentile of the run's boresight-equivalent levels taken as its reference (the
brightest, robust to a few noisy frames)."""

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
    """Samples, inside the FoV or not, that gave a bearing: all of them are scored."""
    rms_error_deg: float
    """RMS of (estimated − true) angle over the valid samples, wrapped to ±180°, degrees."""
    rms_sigma_deg: float
    """RMS of the σ the estimator predicted for the same samples, degrees."""
    max_abs_error_deg: float
    """Largest absolute error, degrees."""
    rejected: dict[str, int]
    """Samples without a bearing, by reason (a sample may count under several)."""
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
    outside_bearings: int = 0
    """Bearings from samples whose true angle lies outside the FoV."""
    confident_wrong: int = 0
    """Bearings whose error exceeds :data:`CONFIDENT_WRONG_SIGMAS` times their σ."""
    constant_rms_deg: float = math.nan
    """RMS error of the best constant guess (the circular mean of the true angles of the
    scored samples) over the same samples, degrees."""

    @property
    def nothing_to_check(self) -> bool:
        """True when no sample gave a bearing."""
        return self.valid == 0

    @property
    def confident_wrong_share(self) -> float:
        """Confident-wrong bearings as a share of all bearings (NaN without bearings)."""
        return self.confident_wrong / self.valid if self.valid else math.nan

    @property
    def few_samples(self) -> bool:
        """True when the measured floor rests on fewer than :data:`MIN_FLOOR_SAMPLES`."""
        return 0 < self.valid < MIN_FLOOR_SAMPLES

    @property
    def constant_beats_bearings(self) -> bool:
        """True when always answering one angle would have had a smaller RMS error."""
        return self.constant_rms_deg <= self.rms_error_deg

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
    def sigma_consistent(self) -> bool:
        """True when the predicted σ matches the observed error within 1.2×."""
        return 1.0 / CONSISTENT_RATIO <= self.ratio <= CONSISTENT_RATIO

    @property
    def consistent(self) -> bool:
        """The verdict: bearings to check, σ honest within 1.2×, at most
        :data:`CONFIDENT_WRONG_MAX` of them confident-wrong, and better than a constant."""
        return (
            not self.nothing_to_check
            and self.sigma_consistent
            and self.confident_wrong_share <= CONFIDENT_WRONG_MAX
            and not self.constant_beats_bearings
        )

    def problems(self) -> list[str]:
        """Why the verdict fails, one phrase each (empty when consistent)."""
        if self.nothing_to_check:
            return ["nothing to check: no sample gave a bearing"]
        out = []
        if not self.sigma_consistent:
            out.append(f"error/σ {self.ratio:.3f} (limit {CONSISTENT_RATIO}×)")
        if not self.confident_wrong_share <= CONFIDENT_WRONG_MAX:
            out.append(
                f"{self.confident_wrong_share:.1%} of bearings confident-wrong "
                f"(error > {CONFIDENT_WRONG_SIGMAS:g}σ; limit {CONFIDENT_WRONG_MAX:.0%})"
            )
        if self.constant_beats_bearings:
            out.append(
                f"a constant guess (RMS {self.constant_rms_deg:.2f}°) beats the bearings "
                f"(RMS {self.rms_error_deg:.2f}°)"
            )
        return out


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


def _wrap_deg(x: Array) -> Array:
    out: Array = (np.asarray(x, dtype=np.float64) + 180.0) % 360.0 - 180.0
    return out


def constant_guess_rms_deg(true_deg: Array) -> float:
    """RMS error (wrapped) of always answering the circular mean of ``true_deg``, degrees."""
    rad = np.radians(np.asarray(true_deg, dtype=np.float64))
    if not len(rad):
        return math.nan
    mean = math.degrees(math.atan2(float(np.mean(np.sin(rad))), float(np.mean(np.cos(rad)))))
    return float(np.sqrt(np.mean(_wrap_deg(np.degrees(rad) - mean) ** 2)))


def with_run_reference(
    cal: Calibration, result: DfResult, samples: TurntableSamples, channel: npt.ArrayLike | None
) -> DfResult:
    """``result`` after the level rule, against the run's own reference level per table.

    A turntable run holds one emitter at one range, so the run's brightest
    boresight-equivalent levels (:data:`REFERENCE_PERCENTILE`) are its level at
    boresight; samples more than the margin below it are refused.
    """
    levels = boresight_levels(cal, result, samples.rssi1_dbm, samples.rssi2_dbm, channel)
    reference = np.full(len(levels), np.nan)
    ch = np.zeros(len(levels), np.int64) if channel is None else np.asarray(channel, np.int64)
    for c in np.unique(ch).tolist():
        mine = (ch == c) & np.isfinite(levels)
        if mine.any():
            reference[ch == c] = np.percentile(levels[mine], REFERENCE_PERCENTILE)
    # one emitter at one range: nothing decays, the fold's drop is judged from the reference
    return refuse_weak(result, levels, reference, fold_margin_db(fold_drops(cal, result, channel)))


def check_calibration(cal: Calibration, samples: TurntableSamples) -> CheckReport:
    """Estimate every sample and compare with the true angle, outside the FoV too.

    Amplitude monopulse cannot tell an angle outside the FoV from one inside
    (the ψ curve folds back), so such samples should be refused by the
    field-of-view rules; those that still give a bearing are scored like the
    others, and the confident-wrong ones among them fail the check.
    """
    channel = samples.channel if any(t.channel is not None for t in cal.tables) else None
    result = estimate(cal, samples.rssi1_dbm, samples.rssi2_dbm, channel)
    result = with_run_reference(cal, result, samples, channel)
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
    ok = result.valid & (table_index >= 0)
    err = _wrap_deg(result.angle_deg[ok].astype(np.float64) - samples.angle_deg[ok])
    sigma = result.sigma_deg[ok].astype(np.float64)
    model2 = np.array([t.model_sigma_deg**2 for t in cal.tables])[table_index[ok]]
    env2 = np.array([t.env_floor_deg**2 for t in cal.tables])[table_index[ok]]
    noise2 = np.maximum(sigma**2 - model2 - env2, 0.0)
    rejected: Counter[str] = Counter()
    for flag in DfFlag:
        if flag is DfFlag.NONE or flag.name is None:
            continue
        count = int(np.count_nonzero((result.flags & np.uint8(flag)) != 0))
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
        outside_bearings=int(np.count_nonzero(ok & ~inside)),
        confident_wrong=int(np.count_nonzero(np.abs(err) > CONFIDENT_WRONG_SIGMAS * sigma)),
        constant_rms_deg=constant_guess_rms_deg(samples.angle_deg[ok]),
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
