"""Bearings-only location of emitters with their covariance, many fixes at once.

N stations at ``(x_i, y_i)`` (metres east/north) measure compass azimuths
``φ_i`` with one-sigma errors ``σ_i``. The estimate is Torrieri's linearised
weighted least squares (method.md §5):

1. a pseudo-linear start: every line of bearing is a linear equation
   ``sin φ_i·x − cos φ_i·y = sin φ_i·x_i − cos φ_i·y_i``; solve them by
   weighted least squares, once with weights ``1/σ_i²`` and once more with
   ``1/(D_i·σ_i)²`` using the ranges of the first solution;
2. damped Gauss-Newton on the wrapped azimuth residuals: the step
   ``(GᵀWG)⁻¹GᵀW·wrap(φ − φ₀)`` is halved until the weighted cost drops,
   with an iteration cap;
3. the covariance ``(GᵀWG)⁻¹`` at the solution, in the closed form with
   ``μ = Σ cos²φ₀ᵢ/(D₀ᵢ²σᵢ²)``, ``λ = Σ sin²φ₀ᵢ/(D₀ᵢ²σᵢ²)``,
   ``ν = Σ sin φ₀ᵢ cos φ₀ᵢ/(D₀ᵢ²σᵢ²)``: ``σ_x² = μ/(μλ − ν²)``,
   ``σ_y² = λ/(μλ − ν²)``, ``σ_xy = ν/(μλ − ν²)`` (math angles; the published
   text prints μ in both variances, λ is right for σ_y²).

A fix is never silently wrong: it carries a :class:`FixStatus` that is not
``OK`` when the lines of bearing are nearly parallel (condition number of the
information matrix), when the error ellipse is so large against the range that
the linearisation does not hold, when the solution lies behind a sensor (its
direction from the sensor differs from the measured bearing by more than 90°),
when three or more bearings are mutually inconsistent (χ² test), or when the
iterations did not converge.

Everything is batched: arrays of shape ``(B, N, …)`` hold ``B`` independent
problems with up to ``N`` bearings each; a NaN azimuth marks a missing bearing.
"""

from __future__ import annotations

import enum
import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.special import chdtri

from rfsas_hw.angles import compass_to_math_rad
from rfsas_hw.errors import BackendError

Array = npt.NDArray[np.float64]

__all__ = [
    "FixStatus",
    "Triangulation",
    "TriangulationBatch",
    "TriangulationOptions",
    "bearing_crb",
    "triangulate",
    "triangulate_batch",
]


class FixStatus(enum.IntEnum):
    """Outcome of one triangulation; anything but ``OK`` means do not trust the fix."""

    OK = 0
    TOO_FEW_BEARINGS = 1
    """Fewer than two usable bearings."""
    ILL_CONDITIONED = 2
    """Nearly parallel lines of bearing, or an error ellipse too large for the linearisation."""
    BEHIND_SENSOR = 3
    """The solution lies behind at least one sensor (residual beyond the limit)."""
    INCONSISTENT = 4
    """Three or more bearings do not meet in one point (χ² test on the residuals)."""
    NOT_CONVERGED = 5
    """Gauss-Newton hit its iteration cap before the step became small."""


_STATUSES = {int(v): v for v in FixStatus}
"""Each status by its number."""


@dataclass(frozen=True, slots=True)
class TriangulationOptions:
    """Tuning of :func:`triangulate_batch`.

    Args:
        max_iterations: Gauss-Newton iteration cap (≥ 1).
        tolerance_m: stop when the step is shorter than this, metres (> 0).
        max_halvings: step halvings tried per iteration before giving up on it.
        max_condition: largest accepted condition number of the information
            matrix GᵀWG (ratio of the squared ellipse axes); two lines of bearing
            crossing at angle α at equal range give ``(1 + cos α)/(1 − cos α)``,
            so the default 1e4 rejects crossings below about 1.1°.
        max_range_fraction: largest accepted ratio of the ellipse's one-sigma
            major semi-axis to the shortest station range; beyond it the
            linearisation (and therefore the covariance) is not trustworthy.
        behind_deg: a residual larger than this (degrees) means the solution is
            behind that sensor.
        consistency_alpha: false-alarm probability of the χ² consistency test
            on ``N − 2`` degrees of freedom (N ≥ 3); 0 disables it.

    Raises:
        BackendError: on a value outside its range.
    """

    max_iterations: int = 25
    tolerance_m: float = 1e-4
    max_halvings: int = 12
    max_condition: float = 1e4
    max_range_fraction: float = 0.1
    behind_deg: float = 90.0
    consistency_alpha: float = 1e-4

    def __post_init__(self) -> None:
        if self.max_iterations < 1:
            raise BackendError(f"max_iterations must be ≥ 1, got {self.max_iterations}")
        if not self.tolerance_m > 0:
            raise BackendError(f"tolerance_m must be > 0, got {self.tolerance_m}")
        if self.max_halvings < 0:
            raise BackendError(f"max_halvings must be ≥ 0, got {self.max_halvings}")
        if not self.max_condition > 1:
            raise BackendError(f"max_condition must be > 1, got {self.max_condition}")
        if not self.max_range_fraction > 0:
            raise BackendError(f"max_range_fraction must be > 0, got {self.max_range_fraction}")
        if not 0 < self.behind_deg <= 180:
            raise BackendError(f"behind_deg must be in (0, 180], got {self.behind_deg}")
        if not 0 <= self.consistency_alpha < 1:
            raise BackendError(f"consistency_alpha must be in [0, 1), got {self.consistency_alpha}")


DEFAULT_OPTIONS = TriangulationOptions()


@dataclass(frozen=True, slots=True)
class Triangulation:
    """One fix: where the emitter is, how well that is known, and whether to trust it."""

    position: Array
    """Estimated emitter position ``(x_m, y_m)``, metres east/north; NaN if none exists."""
    covariance: Array
    """2×2 covariance of ``position``, m² (``[[σ_x², σ_xy], [σ_xy, σ_y²]]``); inf if singular."""
    status: FixStatus
    """Why the fix is or is not trustworthy."""
    reason: str
    """Human-readable explanation of ``status`` with the numbers behind it."""
    gdop: float
    """Position error ``√tr Σ`` over the RMS of ``D_i·σ_i``: geometry's dilution (√2 at 90°)."""
    condition: float
    """Condition number of the information matrix GᵀWG (1 = circular ellipse)."""
    chi2: float
    """Weighted sum of squared azimuth residuals at the solution (N − 2 degrees of freedom)."""
    iterations: int
    """Gauss-Newton iterations used."""
    n_bearings: int
    """Bearings that took part."""

    @property
    def ok(self) -> bool:
        """True when the fix can be used (status ``OK``)."""
        return self.status is FixStatus.OK


@dataclass(frozen=True, slots=True)
class TriangulationBatch:
    """``B`` fixes as arrays; ``batch[i]`` gives the :class:`Triangulation` of row ``i``."""

    position: Array
    """Estimated positions, shape (B, 2), metres east/north."""
    covariance: Array
    """Covariances, shape (B, 2, 2), m²."""
    status: npt.NDArray[np.uint8]
    """:class:`FixStatus` values, shape (B,)."""
    gdop: Array
    """Geometric dilution of precision, shape (B,)."""
    condition: Array
    """Condition number of GᵀWG, shape (B,)."""
    chi2: Array
    """Weighted squared residual sum, shape (B,)."""
    iterations: npt.NDArray[np.int32]
    """Gauss-Newton iterations, shape (B,)."""
    n_bearings: npt.NDArray[np.int32]
    """Usable bearings per fix, shape (B,)."""
    range_fraction: Array
    """One-sigma major semi-axis over the shortest range, shape (B,)."""
    max_residual_deg: Array
    """Largest absolute azimuth residual at the solution, degrees, shape (B,)."""
    chi2_limit: Array
    """χ² threshold applied (inf when the test does not apply), shape (B,)."""

    @property
    def ok(self) -> npt.NDArray[np.bool_]:
        """Boolean mask of trustworthy fixes, shape (B,)."""
        return np.asarray(self.status == FixStatus.OK)

    def __len__(self) -> int:
        return int(self.status.shape[0])

    def reason(self, i: int) -> str:
        """Explanation of row ``i``'s status, with the numbers that decided it."""
        return _reason(
            FixStatus(int(self.status[i])),
            int(self.n_bearings[i]),
            float(self.gdop[i]),
            float(self.condition[i]),
            float(self.range_fraction[i]),
            float(self.max_residual_deg[i]),
            float(self.chi2[i]),
            float(self.chi2_limit[i]),
            int(self.iterations[i]),
        )

    def statuses(self) -> list[FixStatus]:
        """Every row's status as a :class:`FixStatus`."""
        return [_STATUSES[v] for v in self.status.tolist()]

    def reasons(self) -> list[str]:
        """:meth:`reason` of every row (the columns turned into Python numbers once)."""
        return [
            _reason(_STATUSES[st], n, g, c, rf, res, chi2, lim, it)
            for st, n, g, c, rf, res, chi2, lim, it in zip(
                self.status.tolist(),
                self.n_bearings.tolist(),
                self.gdop.tolist(),
                self.condition.tolist(),
                self.range_fraction.tolist(),
                self.max_residual_deg.tolist(),
                self.chi2.tolist(),
                self.chi2_limit.tolist(),
                self.iterations.tolist(),
                strict=True,
            )
        ]

    def __getitem__(self, i: int) -> Triangulation:
        status = FixStatus(int(self.status[i]))
        return Triangulation(
            position=self.position[i].copy(),
            covariance=self.covariance[i].copy(),
            status=status,
            reason=self.reason(i),
            gdop=float(self.gdop[i]),
            condition=float(self.condition[i]),
            chi2=float(self.chi2[i]),
            iterations=int(self.iterations[i]),
            n_bearings=int(self.n_bearings[i]),
        )


def _reason(
    status: FixStatus,
    n: int,
    gdop: float,
    condition: float,
    range_fraction: float,
    max_residual_deg: float,
    chi2: float,
    chi2_limit: float,
    iterations: int,
) -> str:
    if status is FixStatus.OK:
        return f"ok: {n} bearings, GDOP {gdop:.3g}, condition {condition:.3g}"
    if status is FixStatus.TOO_FEW_BEARINGS:
        return f"too few bearings: {n} usable, need 2"
    if status is FixStatus.BEHIND_SENSOR:
        return (
            f"lines of bearing meet behind a sensor: the direction to the solution "
            f"differs from a measured bearing by {max_residual_deg:.1f}°"
        )
    if status is FixStatus.ILL_CONDITIONED:
        if not math.isfinite(condition):
            return "ill-conditioned: lines of bearing are parallel (singular geometry)"
        return (
            f"ill-conditioned: near-parallel lines of bearing or too large an error "
            f"ellipse (condition {condition:.3g}, 1σ major axis "
            f"{range_fraction:.2f} of the shortest range)"
        )
    if status is FixStatus.INCONSISTENT:
        return (
            f"inconsistent bearings: χ² {chi2:.3g} > {chi2_limit:.3g} on {n - 2} degrees of freedom"
        )
    return f"not converged after {iterations} iterations"


def _inputs(stations_xy: Any, azimuths_deg: Any, sigmas_deg: Any) -> tuple[Any, ...]:
    """Check the shapes; the stations (B, N, 2), math angles (B, N), the usable mask
    (B, N), the weights ``1/σ²`` (B, N, rad⁻², 0 where not usable) and usable counts (B,).

    Raises:
        BackendError: mismatched shapes, or a usable bearing whose sigma is not > 0.
    """
    from rfsas_hw.backend import _triangulation_kernel as k

    S = np.ascontiguousarray(stations_xy, dtype=np.float64)
    az = np.asarray(azimuths_deg, dtype=np.float64)
    sg = np.asarray(sigmas_deg, dtype=np.float64)
    if S.ndim != 3 or S.shape[-1] != 2:
        raise BackendError(f"stations_xy must have shape (B, N, 2), got {S.shape}")
    if sg.ndim == 1 and az.ndim == 2 and sg.shape[0] == az.shape[1]:
        sg = np.broadcast_to(sg, az.shape)
    if az.shape != S.shape[:2] or sg.shape != S.shape[:2]:
        raise BackendError(
            f"azimuths_deg {az.shape} and sigmas_deg {sg.shape} must match "
            f"stations_xy {S.shape[:2]}"
        )
    with np.errstate(invalid="ignore"):
        phi = compass_to_math_rad(az)  # NaN where missing: those bearings take no part
    sg = np.ascontiguousarray(sg)
    valid, w, n_valid, b, i = k.prepare(S, phi, sg)
    if b >= 0:
        raise BackendError(f"sigma of bearing {i} in fix {b} must be > 0 degrees, got {sg[b, i]}")
    return S, phi, valid, w, n_valid


@functools.lru_cache(maxsize=64)
def _chi2_limits(n_max: int, alpha: float) -> Array:
    """χ² threshold of the consistency test by number of bearings 0 … ``n_max``
    (inf below three bearings or when the test is off)."""
    limits = np.full(n_max + 1, np.inf)
    if alpha > 0 and n_max >= 3:
        limits[3:] = chdtri(np.arange(1, n_max - 1), alpha)
    limits.flags.writeable = False
    return limits


def bearing_crb(stations_xy: Any, target_xy: Any, sigmas_deg: Any) -> Array:
    """Cramér–Rao bound on the position error: (GᵀWG)⁻¹ at the true position.

    Args:
        stations_xy: station positions, shape (N, 2) or (B, N, 2), metres.
        target_xy: true emitter position, shape (2,) or (B, 2), metres.
        sigmas_deg: bearing one-sigma errors, shape (N,) or (B, N), degrees.

    Returns:
        Covariance bound, m², shape (2, 2) or (B, 2, 2); inf where singular.

    Raises:
        BackendError: on mismatched shapes or a non-positive sigma.
    """
    from rfsas_hw.backend import _triangulation_kernel as k

    single = np.ndim(stations_xy) == 2
    S = np.asarray(stations_xy, np.float64)
    T = np.asarray(target_xy, np.float64)
    sg = np.asarray(sigmas_deg, np.float64)
    if single:
        S, T, sg = S[None], T[None], sg[None]
    if T.shape != (S.shape[0], 2):
        raise BackendError(f"target_xy must have shape (B, 2) = ({S.shape[0]}, 2), got {T.shape}")
    S, _, valid, w, _ = _inputs(S, np.zeros(S.shape[:2]), sg)
    cov = k.information_covariance(S, np.ascontiguousarray(T), w, valid)
    return np.asarray(cov[0] if single else cov, np.float64)


def triangulate_batch(
    stations_xy: Any,
    azimuths_deg: Any,
    sigmas_deg: Any,
    options: TriangulationOptions = DEFAULT_OPTIONS,
) -> TriangulationBatch:
    """Locate ``B`` emitters from their bearings, each with covariance and status.

    Every row is solved by one compiled loop (start, Gauss-Newton, covariance and
    status), so one row costs microseconds and a batch grows linearly.

    Args:
        stations_xy: station positions, shape (B, N, 2), metres east/north.
        azimuths_deg: measured compass azimuths, shape (B, N), degrees clockwise
            from north; NaN marks a missing bearing.
        sigmas_deg: one-sigma bearing errors, shape (B, N) or (N,), degrees (> 0).
        options: iteration and acceptance limits.

    Returns:
        The fixes; rows whose status is not ``OK`` still carry the best position
        found (NaN when none exists) and the covariance there (inf when singular).

    Raises:
        BackendError: on mismatched shapes or a non-positive sigma.
    """
    from rfsas_hw.backend import _triangulation_kernel as k

    S, phi, valid, w, n_valid = _inputs(stations_xy, azimuths_deg, sigmas_deg)
    limits = _chi2_limits(S.shape[1], float(options.consistency_alpha))
    chi2_limit = limits[n_valid]
    position, cov, status, gdop, condition, chi2, iterations, range_fraction, resid = k.solve(
        S,
        phi,
        w,
        valid,
        chi2_limit,
        options.max_iterations,
        options.tolerance_m,
        options.max_halvings,
        options.max_condition,
        options.max_range_fraction,
        options.behind_deg,
    )
    return TriangulationBatch(
        position=position,
        covariance=cov,
        status=status,
        gdop=gdop,
        condition=condition,
        chi2=chi2,
        iterations=iterations,
        n_bearings=n_valid,
        range_fraction=range_fraction,
        max_residual_deg=resid,
        chi2_limit=chi2_limit,
    )


def triangulate(
    stations_xy: Any,
    azimuths_deg: Any,
    sigmas_deg: Any,
    options: TriangulationOptions = DEFAULT_OPTIONS,
) -> Triangulation:
    """Locate one emitter from N ≥ 2 bearings: :func:`triangulate_batch` of one row.

    Args:
        stations_xy: station positions, shape (N, 2), metres east/north.
        azimuths_deg: measured compass azimuths, shape (N,), degrees clockwise from north.
        sigmas_deg: one-sigma bearing errors, shape (N,), degrees (> 0).
        options: iteration and acceptance limits.

    Returns:
        The fix; check ``.ok`` (and ``.reason``) before using ``.position``.

    Raises:
        BackendError: on mismatched shapes or a non-positive sigma.
    """
    S = np.asarray(stations_xy, np.float64)
    az = np.asarray(azimuths_deg, np.float64)
    sg = np.asarray(sigmas_deg, np.float64)
    if S.ndim != 2 or az.ndim != 1:
        raise BackendError(
            f"triangulate takes stations (N, 2) and azimuths (N,), got {S.shape} and {az.shape}"
        )
    sg = np.broadcast_to(sg, az.shape) if sg.ndim == 0 else sg
    return triangulate_batch(S[None], az[None], sg[None], options)[0]
