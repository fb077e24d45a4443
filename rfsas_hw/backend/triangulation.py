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


_TWO_PI = 2 * np.pi
_add = np.add.reduce
"""``np.sum`` without its Python wrapper (the same reduction)."""


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


def _inputs(
    stations_xy: Any, azimuths_deg: Any, sigmas_deg: Any
) -> tuple[Array, Array, Array, npt.NDArray[np.bool_]]:
    """Validate and broadcast to (B, N, 2), (B, N), (B, N) plus the usable mask."""
    S = np.asarray(stations_xy, dtype=np.float64)
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
    valid = np.isfinite(az) & np.isfinite(sg) & np.isfinite(S).all(axis=-1)
    bad_sigma = valid & ~(sg > 0)
    if bad_sigma.any():
        b, i = np.argwhere(bad_sigma)[0]
        raise BackendError(f"sigma of bearing {i} in fix {b} must be > 0 degrees, got {sg[b, i]}")
    return S, az, sg, valid


def _lines_wls(S: Array, phi: Array, w: Array) -> Array:
    """Weighted least-squares intersection of lines of bearing, shape (B, 2)."""
    s, c = np.sin(phi), np.cos(phi)
    rhs = s * S[..., 0] - c * S[..., 1]
    a11 = np.sum(w * s * s, axis=1)
    a12 = -np.sum(w * s * c, axis=1)
    a22 = np.sum(w * c * c, axis=1)
    b1 = np.sum(w * s * rhs, axis=1)
    b2 = -np.sum(w * c * rhs, axis=1)
    det = a11 * a22 - a12 * a12
    # relative test: exactly parallel lines leave only round-off in det
    det = np.where(det > 1e-12 * (a11 + a22) ** 2, det, np.nan)
    return np.stack([(a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det], axis=-1)


def _geometry(p: Array, S: Array, phi: Array) -> tuple[Array, Array, Array, Array]:
    """Predicted azimuth (math rad), squared range, wrapped residual, offset (B, N, 2)."""
    d = p[:, None, :] - S
    dx, dy = d[..., 0], d[..., 1]
    d2 = dx * dx + dy * dy
    phi0 = np.arctan2(dy, dx)
    # wrap_rad_pi, inlined: this runs every iteration
    return phi0, d2, np.pi - np.mod(np.pi - (phi - phi0), _TWO_PI), d


def _cost(p: Array, S: Array, phi: Array, w: Array) -> Array:
    _, _, r, _ = _geometry(p, S, phi)
    cost: Array = _add(w * r * r, axis=1)
    return cost


def _information(phi0: Array, d2: Array, w: Array) -> tuple[Array, Array, Array]:
    """μ, λ, ν of method.md §5 (math angles), each shape (B,)."""
    c, s = np.cos(phi0), np.sin(phi0)
    wd = w / d2
    mu = np.sum(wd * c * c, axis=1)
    lam = np.sum(wd * s * s, axis=1)
    nu = np.sum(wd * s * c, axis=1)
    return mu, lam, nu


def _closed_form_cov(mu: Array, lam: Array, nu: Array) -> tuple[Array, Array]:
    """Covariance (B, 2, 2) from μ, λ, ν and the determinant μλ − ν²."""
    det = mu * lam - nu * nu
    safe = np.where(det > 0, det, np.nan)
    cov = np.empty((*mu.shape, 2, 2))
    cov[:, 0, 0] = mu / safe
    cov[:, 1, 1] = lam / safe
    cov[:, 0, 1] = cov[:, 1, 0] = nu / safe
    cov[~(det > 0)] = np.inf
    return cov, det


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
    single = np.ndim(stations_xy) == 2
    S = np.asarray(stations_xy, np.float64)
    T = np.asarray(target_xy, np.float64)
    sg = np.asarray(sigmas_deg, np.float64)
    if single:
        S, T, sg = S[None], T[None], sg[None]
    if T.shape != (S.shape[0], 2):
        raise BackendError(f"target_xy must have shape (B, 2) = ({S.shape[0]}, 2), got {T.shape}")
    S, _, sg, valid = _inputs(S, np.zeros(S.shape[:2]), sg)
    w = np.where(valid, 1.0 / np.deg2rad(np.where(valid, sg, 1.0)) ** 2, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = T[:, None, :] - S
        phi0 = np.arctan2(d[..., 1], d[..., 0])
        d2 = np.where(valid, np.sum(d * d, axis=-1), 1.0)
        cov, _ = _closed_form_cov(*_information(phi0, d2, w))
    return np.asarray(cov[0] if single else cov, np.float64)


def triangulate_batch(
    stations_xy: Any,
    azimuths_deg: Any,
    sigmas_deg: Any,
    options: TriangulationOptions = DEFAULT_OPTIONS,
) -> TriangulationBatch:
    """Locate ``B`` emitters from their bearings, each with covariance and status.

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
    S, az, sg, valid = _inputs(stations_xy, azimuths_deg, sigmas_deg)
    B = S.shape[0]
    n_valid = valid.sum(axis=1).astype(np.int32)
    S = np.where(valid[..., None], S, 0.0)
    phi = np.where(valid, compass_to_math_rad(np.where(valid, az, 0.0)), 0.0)
    w = np.where(valid, 1.0 / np.deg2rad(np.where(valid, sg, 1.0)) ** 2, 0.0)
    iterations = np.zeros(B, np.int32)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        p = _lines_wls(S, phi, w)
        d2 = np.sum((p[:, None, :] - S) ** 2, axis=-1)
        refined = _lines_wls(S, phi, w / np.maximum(d2, 1e-6))
        p = np.where(np.isfinite(refined), refined, p)
        solvable = np.isfinite(p).all(axis=1) & (n_valid >= 2)
        p = np.where(solvable[:, None], p, 0.0)
        p_start = p.copy()
        _, _, r_start, _ = _geometry(p, S, phi)
        start_behind = solvable & (
            np.max(np.where(valid, np.abs(r_start), 0.0), axis=1) > np.deg2rad(options.behind_deg)
        )
        # two lines that meet behind a sensor have no solution in front of both
        converged = ~solvable | (start_behind & (n_valid == 2))
        for done in range(options.max_iterations):
            # only the rows still iterating: the others keep their solution
            act = np.flatnonzero(~converged)
            if not len(act):
                break
            if len(act) <= _SCALAR_ROWS:
                # the last few rows: the same iterations in plain floats (numpy's
                # per-call cost would dominate), bit for bit what the arrays give
                for i in act.tolist():
                    row = _iterate_row(
                        float(p[i, 0]),
                        float(p[i, 1]),
                        S[i, :, 0].tolist(),
                        S[i, :, 1].tolist(),
                        phi[i].tolist(),
                        w[i].tolist(),
                        options.max_iterations - done,
                        options,
                    )
                    p[i] = row[0], row[1]
                    iterations[i] += row[2]
                    converged[i] = row[3]
                break
            iterations[act] += 1
            pa, Sa, phia, wa = p[act], S[act], phi[act], w[act]
            phi0, d2, r, _ = _geometry(pa, Sa, phia)
            d2 = np.maximum(d2, 1e-12)
            c, s = np.cos(phi0), np.sin(phi0)
            wd = wa / d2
            mu = _add(wd * c * c, axis=1)
            lam = _add(wd * s * s, axis=1)
            nu = _add(wd * s * c, axis=1)
            det = mu * lam - nu * nu
            # gradient Gᵀ W r with G rows [−sin φ₀/D, cos φ₀/D]
            root = np.sqrt(d2)
            g1 = _add(wa * (-s) * r / root, axis=1)
            g2 = _add(wa * c * r / root, axis=1)
            det_safe = np.where(det > 0, det, np.nan)
            step = np.stack([(mu * g1 + nu * g2) / det_safe, (nu * g1 + lam * g2) / det_safe], -1)
            bad = ~np.isfinite(step).all(axis=1)
            step[bad] = 0.0
            cost0 = _add(wa * r * r, axis=1)
            limit = cost0 * (1 + 1e-12) + 1e-300
            accepted = bad.copy()
            cand = pa.copy()
            # the full step first; where it does not lower the cost, every halving
            # 2^-1 … 2^-max_halvings at once, taking the first that does
            trial = pa + step
            better = ~accepted & (_cost(trial, Sa, phia, wa) <= limit)
            cand[better] = trial[better]
            accepted |= better
            rest = np.flatnonzero(~accepted)
            if len(rest) and options.max_halvings:
                H = options.max_halvings
                alpha = 0.5 ** np.arange(1, H + 1)
                trials = pa[rest, None, :] + alpha[None, :, None] * step[rest, None, :]
                costs = _cost(
                    trials.reshape(-1, 2),
                    np.repeat(Sa[rest], H, axis=0),
                    np.repeat(phia[rest], H, axis=0),
                    np.repeat(wa[rest], H, axis=0),
                ).reshape(len(rest), H)
                ok = costs <= limit[rest, None]
                found = ok.any(axis=1)
                first = np.argmax(ok, axis=1)
                took = rest[found]
                cand[took] = trials[found, first[found]]
                accepted[took] = True
            moved = np.hypot(*(cand - pa).T)
            p[act] = cand
            # a step that could not reduce the cost means we sit at the minimum
            converged[act] = (moved < options.tolerance_m) | ~accepted | bad

        phi0, d2, r, _ = _geometry(p, S, phi)
        d2 = np.where(valid, np.maximum(d2, 1e-12), 1.0)
        mu, lam, nu = _information(phi0, d2, w)
        cov, det = _closed_form_cov(mu, lam, nu)
        tr = mu + lam
        disc = np.sqrt(np.maximum(tr * tr / 4 - det, 0.0))
        e_max, e_min = tr / 2 + disc, tr / 2 - disc
        condition = np.where(e_min > 0, e_max / e_min, np.inf)
        major = np.where(e_min > 0, 1.0 / np.sqrt(e_min), np.inf)
        d_min = np.sqrt(np.min(np.where(valid, d2, np.inf), axis=1))
        range_fraction = major / d_min
        chi2 = np.sum(w * r * r, axis=1)
        abs_r = np.where(valid, np.abs(r), 0.0)
        max_residual_deg = np.rad2deg(np.max(abs_r, axis=1, initial=0.0))
        scale = np.sqrt(np.sum(np.where(valid, d2 / w, 0.0), axis=1) / np.maximum(n_valid, 1))
        gdop = np.sqrt(cov[:, 0, 0] + cov[:, 1, 1]) / scale
        dof = np.maximum(n_valid - 2, 1)
        chi2_limit = np.full(B, np.inf)
        if options.consistency_alpha > 0:
            chi2_limit = np.where(n_valid >= 3, chdtri(dof, options.consistency_alpha), np.inf)

    status = np.full(B, FixStatus.OK, np.uint8)
    status[~converged] = FixStatus.NOT_CONVERGED
    status[chi2 > chi2_limit] = FixStatus.INCONSISTENT
    status[max_residual_deg > options.behind_deg] = FixStatus.BEHIND_SENSOR
    ill = ~np.isfinite(condition) | (condition > options.max_condition)
    ill |= ~(range_fraction <= options.max_range_fraction)
    status[ill] = FixStatus.ILL_CONDITIONED
    behind_start = start_behind & (ill | (max_residual_deg > options.behind_deg))
    status[behind_start] = FixStatus.BEHIND_SENSOR
    # report the residual that proves it: at the lines' intersection
    start_resid_deg = np.rad2deg(np.max(np.where(valid, np.abs(r_start), 0.0), axis=1))
    max_residual_deg = np.where(behind_start, start_resid_deg, max_residual_deg)
    status[~solvable & (n_valid >= 2)] = FixStatus.ILL_CONDITIONED
    status[n_valid < 2] = FixStatus.TOO_FEW_BEARINGS
    position = np.where(behind_start[:, None], p_start, p)
    position = np.where(solvable[:, None], position, np.nan)
    cov[~solvable] = np.inf
    return TriangulationBatch(
        position=position,
        covariance=cov,
        status=status,
        gdop=np.where(solvable, gdop, np.inf),
        condition=np.where(solvable, condition, np.inf),
        chi2=np.where(solvable, chi2, np.nan),
        iterations=iterations,
        n_bearings=n_valid,
        range_fraction=np.where(solvable, range_fraction, np.inf),
        max_residual_deg=np.where(solvable, max_residual_deg, np.nan),
        chi2_limit=chi2_limit,
    )


_SCALAR_ROWS = 10
"""When this few fixes are still iterating, :func:`triangulate_batch` finishes them in floats."""


_SHORT_ROW = 8
"""Rows shorter than this are summed by numpy left to right from the first element (from
eight elements on, its pairwise summation adds in eight lanes)."""


def _sum(values: list[float]) -> float:
    """Sum in numpy's order for a short row (left to right from the first element; rows of
    :data:`_SHORT_ROW` or more elements can differ from numpy's sum in the last bit)."""
    total = values[0]
    for v in values[1:]:
        total += v
    return total


def _row_geometry(
    px: float, py: float, xs: list[float], ys: list[float], phis: list[float]
) -> tuple[list[float], list[float], list[float]]:
    """:func:`_geometry` of one row in floats: predicted azimuth, squared range, residual."""
    two_pi = 2 * np.pi
    phi0, d2, r = [], [], []
    for x, y, phi in zip(xs, ys, phis, strict=True):
        dx, dy = px - x, py - y
        p0 = math.atan2(dy, dx)
        phi0.append(p0)
        d2.append(dx * dx + dy * dy)
        r.append(np.pi - ((np.pi - (phi - p0)) % two_pi))
    return phi0, d2, r


def _row_cost(
    px: float, py: float, xs: list[float], ys: list[float], phis: list[float], ws: list[float]
) -> float:
    """:func:`_cost` of one row in floats: ``_sum`` of w·r² with :func:`_row_geometry`'s r."""
    two_pi = 2 * np.pi
    total = 0.0
    first = True
    for x, y, phi, w in zip(xs, ys, phis, ws, strict=True):
        v = np.pi - ((np.pi - (phi - math.atan2(py - y, px - x))) % two_pi)
        if first:
            total, first = w * v * v, False
        else:
            total += w * v * v
    return total


def _iterate_row(
    px: float,
    py: float,
    xs: list[float],
    ys: list[float],
    phis: list[float],
    ws: list[float],
    passes: int,
    options: TriangulationOptions,
) -> tuple[float, float, int, bool]:
    """Up to ``passes`` Gauss-Newton iterations of one row of :func:`triangulate_batch`.

    The same operations in the same order as the batch loop (every column,
    padded ones with weight 0; sums left to right as numpy sums a short row;
    ``np.hypot`` for the step length), so the row ends exactly where the batch
    path would have taken it. Returns the position, the iterations done and
    whether it converged.
    """
    iterations = 0
    converged = False
    # the geometry at the current point: an accepted full step's trial geometry is kept
    geo: tuple[list[float], list[float], list[float]] | None = None
    for _ in range(passes):
        iterations += 1
        phi0, d2, r = geo if geo is not None else _row_geometry(px, py, xs, ys, phis)
        geo = None
        # μ, λ, ν, the gradient and the cost in one pass, each summed as _sum sums
        # (left to right from the first column), term by term as the arrays have it
        mu = lam = nu = g1 = g2 = cost = 0.0
        for k, (p0, dd, v, w) in enumerate(zip(phi0, d2, r, ws, strict=True)):
            dd = max(dd, 1e-12)
            c, s = math.cos(p0), math.sin(p0)
            wd = w / dd
            q = math.sqrt(dd)
            if k:
                mu += wd * c * c
                lam += wd * s * s
                nu += wd * s * c
                g1 += w * (-s) * v / q
                g2 += w * c * v / q
                cost += w * v * v
            else:
                mu, lam, nu = wd * c * c, wd * s * s, wd * s * c
                g1, g2, cost = w * (-s) * v / q, w * c * v / q, w * v * v
        det = mu * lam - nu * nu
        det_safe = det if det > 0 else math.nan
        sx, sy = (mu * g1 + nu * g2) / det_safe, (nu * g1 + lam * g2) / det_safe
        bad = not (math.isfinite(sx) and math.isfinite(sy))
        if bad:
            sx = sy = 0.0
        limit = cost * (1 + 1e-12) + 1e-300
        accepted = bad
        cx, cy = px, py
        if not accepted:
            tx, ty = px + sx, py + sy
            trial = _row_geometry(tx, ty, xs, ys, phis)
            if _sum([w * v * v for w, v in zip(ws, trial[2], strict=True)]) <= limit:
                cx, cy, accepted = tx, ty, True
                geo = trial
            elif len(xs) < _SHORT_ROW:
                # the halvings the batch path tries at once, in its order: the first
                # that lowers the cost wins (the same trial points, 2^-k exact)
                for k in range(1, options.max_halvings + 1):
                    alpha = 0.5**k
                    tx, ty = px + alpha * sx, py + alpha * sy
                    if _row_cost(tx, ty, xs, ys, phis, ws) <= limit:
                        cx, cy, accepted = tx, ty, True
                        break
            elif options.max_halvings:
                # a long row: numpy sums it in another order than _sum, so its costs
                # come from the array code itself
                alphas = 0.5 ** np.arange(1, options.max_halvings + 1)
                trials = np.stack([px + alphas * sx, py + alphas * sy], axis=-1)
                H = len(alphas)
                costs = _cost(
                    trials,
                    np.broadcast_to(np.stack([xs, ys], axis=-1), (H, len(xs), 2)),
                    np.broadcast_to(np.asarray(phis), (H, len(phis))),
                    np.broadcast_to(np.asarray(ws), (H, len(ws))),
                )
                ok = np.flatnonzero(costs <= limit)
                if len(ok):
                    cx, cy = float(trials[ok[0], 0]), float(trials[ok[0], 1])
                    accepted = True
        moved = float(np.hypot(cx - px, cy - py))
        px, py = cx, cy
        converged = moved < options.tolerance_m or not accepted or bad
        if converged:
            break
    return px, py, iterations, converged


def _wls_one(
    xs: list[float], ys: list[float], phis: list[float], ws: list[float]
) -> tuple[float, float] | None:
    """:func:`_lines_wls` for one problem in plain floats (None when singular)."""
    a11 = a12 = a22 = b1 = b2 = 0.0
    for x, y, phi, w in zip(xs, ys, phis, ws, strict=True):
        s, c = math.sin(phi), math.cos(phi)
        rhs = s * x - c * y
        a11 += w * s * s
        a12 -= w * s * c
        a22 += w * c * c
        b1 += w * s * rhs
        b2 -= w * c * rhs
    det = a11 * a22 - a12 * a12
    if not det > 1e-12 * (a11 + a22) ** 2:
        return None
    px, py = (a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det
    return (px, py) if math.isfinite(px) and math.isfinite(py) else None


def _resid_one(
    px: float, py: float, xs: list[float], ys: list[float], phis: list[float]
) -> tuple[list[float], list[float], list[float]]:
    """Predicted azimuths (math rad), squared ranges and wrapped residuals."""
    phi0 = [math.atan2(py - y, px - x) for x, y in zip(xs, ys, strict=True)]
    d2 = [(px - x) ** 2 + (py - y) ** 2 for x, y in zip(xs, ys, strict=True)]
    two_pi = 2 * math.pi
    # same wrap as wrap_rad_pi: into (−π, π]
    r = [math.pi - ((math.pi - (p - q)) % two_pi) for p, q in zip(phis, phi0, strict=True)]
    return phi0, d2, r


def _trial_cost(
    px: float, py: float, xs: list[float], ys: list[float], phis: list[float], ws: list[float]
) -> float:
    """``sum(w·r²)`` with :func:`_resid_one`'s residuals, without its lists."""
    two_pi = 2 * math.pi
    total = 0.0
    for x, y, phi, w in zip(xs, ys, phis, ws, strict=True):
        v = math.pi - ((math.pi - (phi - math.atan2(py - y, px - x))) % two_pi)
        total += w * v * v
    return total


def _info_one(phi0: list[float], d2: list[float], ws: list[float]) -> tuple[float, float, float]:
    mu = lam = nu = 0.0
    for p, dd, w in zip(phi0, d2, ws, strict=True):
        c, s = math.cos(p), math.sin(p)
        wd = w / dd
        mu += wd * c * c
        lam += wd * s * s
        nu += wd * s * c
    return mu, lam, nu


def _triangulate_one(
    xs: list[float],
    ys: list[float],
    phis: list[float],
    ws: list[float],
    options: TriangulationOptions,
) -> Triangulation:
    """:func:`triangulate_batch` for one fix of usable bearings, in plain floats.

    Numpy's per-call overhead dominates a problem of a few bearings, so a single
    fix is solved with :mod:`math`; the batch path is the reference it is
    tested against, step for step.
    """
    n = len(xs)
    inf, nan = math.inf, math.nan
    if n < 2:
        return Triangulation(
            np.full(2, nan),
            np.full((2, 2), inf),
            FixStatus.TOO_FEW_BEARINGS,
            _reason(FixStatus.TOO_FEW_BEARINGS, n, inf, inf, inf, nan, nan, inf, 0),
            inf,
            inf,
            nan,
            0,
            n,
        )
    start = _wls_one(xs, ys, phis, ws)
    if start is not None:
        d2 = [(start[0] - x) ** 2 + (start[1] - y) ** 2 for x, y in zip(xs, ys, strict=True)]
        refined = _wls_one(xs, ys, phis, [w / max(d, 1e-6) for w, d in zip(ws, d2, strict=True)])
        start = refined if refined is not None else start
    if start is None:
        status = FixStatus.ILL_CONDITIONED
        return Triangulation(
            np.full(2, nan),
            np.full((2, 2), inf),
            status,
            _reason(status, n, inf, inf, inf, nan, nan, inf, 0),
            inf,
            inf,
            nan,
            0,
            n,
        )
    px, py = start
    # the geometry at the current point, kept from the accepted trial of the last step
    geo = _resid_one(px, py, xs, ys, phis)
    r_start = geo[2]
    start_resid_deg = math.degrees(max(abs(v) for v in r_start))
    start_behind = start_resid_deg > options.behind_deg
    converged = start_behind and n == 2
    iterations = 0
    for _ in range(options.max_iterations):
        if converged:
            break
        iterations += 1
        phi0, d2, r = geo
        d2 = [max(d, 1e-12) for d in d2]
        mu = lam = nu = g1 = g2 = 0.0
        for p, dd, w, v in zip(phi0, d2, ws, r, strict=True):
            c, sn = math.cos(p), math.sin(p)
            wd = w / dd
            mu += wd * c * c
            lam += wd * sn * sn
            nu += wd * sn * c
            root = math.sqrt(dd)
            g1 += w * (-sn) * v / root
            g2 += w * c * v / root
        det = mu * lam - nu * nu
        if det > 0:
            sx, sy = (mu * g1 + nu * g2) / det, (nu * g1 + lam * g2) / det
        else:
            sx = sy = nan
        if not (math.isfinite(sx) and math.isfinite(sy)):
            converged = True
            break
        cost0 = sum(w * v * v for w, v in zip(ws, r, strict=True))
        alpha = 1.0
        accepted = False
        limit = cost0 * (1 + 1e-12) + 1e-300
        for _ in range(options.max_halvings + 1):
            tx, ty = px + alpha * sx, py + alpha * sy
            if _trial_cost(tx, ty, xs, ys, phis, ws) <= limit:
                accepted = True
                break
            alpha /= 2
        moved = math.hypot(tx - px, ty - py) if accepted else 0.0
        if accepted:
            px, py = tx, ty
            geo = _resid_one(tx, ty, xs, ys, phis)  # the same numbers the trial had
        converged = moved < options.tolerance_m or not accepted
    phi0, d2, r = geo
    d2 = [max(d, 1e-12) for d in d2]
    mu, lam, nu = _info_one(phi0, d2, ws)
    det = mu * lam - nu * nu
    if det > 0:
        cov = np.array([[mu / det, nu / det], [nu / det, lam / det]])
    else:
        cov = np.full((2, 2), inf)
    tr = mu + lam
    disc = math.sqrt(max(tr * tr / 4 - det, 0.0))
    e_max, e_min = tr / 2 + disc, tr / 2 - disc
    condition = e_max / e_min if e_min > 0 else inf
    major = 1.0 / math.sqrt(e_min) if e_min > 0 else inf
    range_fraction = major / math.sqrt(min(d2))
    chi2 = sum(w * v * v for w, v in zip(ws, r, strict=True))
    max_residual_deg = math.degrees(max(abs(v) for v in r))
    scale = math.sqrt(sum(d / w for d, w in zip(d2, ws, strict=True)) / n)
    gdop = math.sqrt(float(cov[0, 0] + cov[1, 1])) / scale
    chi2_limit = inf
    if options.consistency_alpha > 0 and n >= 3:
        chi2_limit = float(chdtri(n - 2, options.consistency_alpha))
    status = FixStatus.OK
    if not converged:
        status = FixStatus.NOT_CONVERGED
    if chi2 > chi2_limit:
        status = FixStatus.INCONSISTENT
    if max_residual_deg > options.behind_deg:
        status = FixStatus.BEHIND_SENSOR
    ill = not math.isfinite(condition) or condition > options.max_condition
    ill = ill or not range_fraction <= options.max_range_fraction
    if ill:
        status = FixStatus.ILL_CONDITIONED
    position = np.array([px, py])
    if start_behind and (ill or max_residual_deg > options.behind_deg):
        status = FixStatus.BEHIND_SENSOR
        max_residual_deg = start_resid_deg
        position = np.array(start)
    return Triangulation(
        position=position,
        covariance=cov,
        status=status,
        reason=_reason(
            status,
            n,
            gdop,
            condition,
            range_fraction,
            max_residual_deg,
            chi2,
            chi2_limit,
            iterations,
        ),
        gdop=gdop,
        condition=condition,
        chi2=chi2,
        iterations=iterations,
        n_bearings=n,
    )


def triangulate(
    stations_xy: Any,
    azimuths_deg: Any,
    sigmas_deg: Any,
    options: TriangulationOptions = DEFAULT_OPTIONS,
) -> Triangulation:
    """Locate one emitter from N ≥ 2 bearings.

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
    S, az, sg, valid = _inputs(S[None], az[None], sg[None])
    keep = valid[0]
    return _triangulate_one(
        S[0, keep, 0].tolist(),
        S[0, keep, 1].tolist(),
        compass_to_math_rad(az[0, keep]).tolist(),
        (1.0 / np.deg2rad(sg[0, keep]) ** 2).tolist(),
        options,
    )
