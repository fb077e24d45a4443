"""Probability that two uncertain oriented boxes overlap (method.md §6).

The vehicle and the threat each occupy an oriented rectangle (length along the
heading × width across it) whose centre is Gaussian. Two estimators:

- **exact** (default): the relative position ``r = x_t − x_v`` is Gaussian
  ``N(μ_t − μ_v, Σ_v + Σ_t)`` and the boxes overlap iff ``r`` lies in the
  Minkowski sum of the two centred boxes — a centrally symmetric octagon
  (a zonotope with the four box edges as generators). Whitened with the
  Cholesky factor it stays a convex polygon; its standard-normal mass is a
  sum over edges of signed triangles from the origin, each split at the foot
  of the perpendicular into two right triangles of mass
  ``arctan(a)/(2π) − T(h, a)`` (leg ``h`` along the normal, slope ``a``,
  Owen's T from :func:`scipy.special.owens_t`). Exact to round-off.
- **montecarlo**: Lambert's estimator — draw both centres (and, optionally,
  headings), test the boxes with the separating-axis theorem, count. It is the
  reference the exact method is tested against, and the only one that handles
  heading uncertainty.

Positions are metres east/north, headings compass degrees, covariances 2×2 m²,
sizes ``(length_m, width_m)`` along and across the heading.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import numpy.typing as npt
from scipy.special import owens_t

from rfsas_hw.angles import compass_to_math_rad
from rfsas_hw.errors import BackendError

Array = npt.NDArray[np.float64]
Size = tuple[float, float]

__all__ = [
    "THREAT_SIZES",
    "VEHICLE_SIGMA_ACROSS_M",
    "VEHICLE_SIGMA_ALONG_M",
    "VEHICLE_SIZE",
    "MonteCarloEstimate",
    "collision_probability",
    "collision_probability_batch",
    "collision_probability_mc",
    "heading_covariance",
    "minkowski_octagon",
    "threat_box",
]

VEHICLE_SIZE: Size = (4.5, 1.8)
"""Default vehicle box: length 4.5 m along the heading, width 1.8 m."""
VEHICLE_SIGMA_ALONG_M = 3.0
"""Default one-sigma vehicle position error along the direction of motion, metres."""
VEHICLE_SIGMA_ACROSS_M = 1.0
"""Default one-sigma vehicle position error across the direction of motion, metres."""

THREAT_SIZES: Mapping[str, Size] = {
    "pedestrian": (0.5, 0.5),
    "cyclist": (1.8, 0.6),
    "vehicle": (4.5, 1.8),
}
"""Box ``(length_m, width_m)`` of each kind of threat."""


def threat_box(kind_or_size: str | Size | Any) -> Size:
    """The box of a threat kind (``pedestrian``, ``cyclist``, ``vehicle``) or a given size.

    Raises:
        BackendError: unknown kind, or a size that is not two non-negative numbers.
    """
    if isinstance(kind_or_size, str):
        try:
            return THREAT_SIZES[kind_or_size]
        except KeyError as err:
            kinds = ", ".join(THREAT_SIZES)
            raise BackendError(f"unknown threat kind {kind_or_size!r}; one of {kinds}") from err
    return _size(kind_or_size, "threat_size")


def _size(value: Any, name: str) -> Size:
    arr = np.asarray(value, np.float64)
    if arr.shape != (2,) or not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise BackendError(f"{name} must be (length_m, width_m) ≥ 0, got {value!r}")
    return float(arr[0]), float(arr[1])


def heading_covariance(
    heading_deg: float,
    sigma_along_m: float = VEHICLE_SIGMA_ALONG_M,
    sigma_across_m: float = VEHICLE_SIGMA_ACROSS_M,
) -> Array:
    """2×2 east/north covariance (m²) with the given sigmas along and across a compass heading.

    Raises:
        BackendError: a negative sigma.
    """
    if sigma_along_m < 0 or sigma_across_m < 0:
        raise BackendError(
            f"position sigmas must be ≥ 0 m, got along {sigma_along_m}, across {sigma_across_m}"
        )
    a = compass_to_math_rad(float(heading_deg))
    c, s = math.cos(a), math.sin(a)  # u = (c, s) along, n = (−s, c) across
    along, across = sigma_along_m**2, sigma_across_m**2
    xy = along * (c * s) + across * (-s * c)
    return np.array(
        [[along * (c * c) + across * (s * s), xy], [xy, along * (s * s) + across * (c * c)]]
    )


def _cov(value: Any, name: str, shape: tuple[int, ...]) -> Array:
    """``value`` as covariances of shape ``(*shape, 2, 2)``, m².

    Raises:
        BackendError: another shape, a non-finite entry, or a matrix that is not
            symmetric positive semi-definite (the row is named).
    """
    from rfsas_hw.backend import _collision_kernel as k

    arr = np.asarray(value, np.float64)
    if arr.shape != (*shape, 2, 2):
        raise BackendError(f"{name} must have shape {(*shape, 2, 2)}, got {arr.shape}")
    row, why = k.first_bad_covariance(arr.reshape(-1, 2, 2))
    if row >= 0:
        where = f" (row {row})" if shape else ""
        if why == 1:
            raise BackendError(f"{name} must be finite{where}")
        raise BackendError(f"{name} must be a symmetric positive semi-definite 2×2 matrix{where}")
    return arr


def _shaped(value: Any, name: str, shape: tuple[int, ...], what: str) -> Array:
    """``value`` as a float array of ``shape`` (its values are checked by the batch)."""
    arr = np.asarray(value, np.float64)
    if arr.shape != shape:
        raise BackendError(f"{name} must be {what}, got {value!r}")
    return arr


def _axes(heading_deg: Array) -> tuple[Array, Array]:
    """Unit vectors along and across (90° left of) a compass heading, shape (..., 2)."""
    a = compass_to_math_rad(np.asarray(heading_deg, np.float64))
    u = np.stack([np.cos(a), np.sin(a)], axis=-1)
    n = np.stack([-u[..., 1], u[..., 0]], axis=-1)
    return u, n


def minkowski_octagon(
    size_a: Array, heading_a_deg: Array, size_b: Array, heading_b_deg: Array
) -> Array:
    """Vertices of ``A ⊕ B`` for centred boxes, counter-clockwise, shape (B, 8, 2).

    The sum of two centred rectangles is the zonotope generated by their four
    edge vectors. Oriented into the upper half-plane and sorted by angle, the
    generators walk the lower boundary from ``−½Σg``; their negatives walk
    back along the upper one.

    Args:
        size_a, size_b: ``(length_m, width_m)`` of the boxes, shape (B, 2).
        heading_a_deg, heading_b_deg: compass headings, shape (B,).
    """
    from rfsas_hw.backend import _collision_kernel as k

    B = len(size_a)
    return k.octagons(
        np.ascontiguousarray(np.broadcast_to(np.asarray(size_a, np.float64), (B, 2))),
        compass_to_math_rad(np.broadcast_to(np.asarray(heading_a_deg, np.float64), (B,))),
        np.ascontiguousarray(np.broadcast_to(np.asarray(size_b, np.float64), (B, 2))),
        compass_to_math_rad(np.broadcast_to(np.asarray(heading_b_deg, np.float64), (B,))),
    )


def collision_probability_batch(
    vehicle_xy: Any,
    vehicle_heading_deg: Any,
    vehicle_cov: Any,
    vehicle_size: Any,
    threat_xy: Any,
    threat_heading_deg: Any,
    threat_cov: Any,
    threat_size: Any,
) -> Array:
    """Exact overlap probability of ``B`` vehicle/threat pairs, vectorised.

    Args:
        vehicle_xy: vehicle centres, shape (B, 2), metres east/north.
        vehicle_heading_deg: vehicle headings, shape (B,) or (), compass degrees.
        vehicle_cov: vehicle position covariances, shape (B, 2, 2) or (2, 2), m².
        vehicle_size: ``(length_m, width_m)``, shape (B, 2) or (2,).
        threat_xy: threat centres, shape (B, 2), metres.
        threat_heading_deg: threat headings, shape (B,) or (), compass degrees.
        threat_cov: threat position covariances, shape (B, 2, 2) or (2, 2), m².
        threat_size: ``(length_m, width_m)``, shape (B, 2) or (2,).

    Returns:
        Probabilities in [0, 1], shape (B,).

    Raises:
        BackendError: mismatched shapes, non-finite values, a covariance that
            is not symmetric positive semi-definite, or a negative size.
    """
    from rfsas_hw.backend import _collision_kernel as k

    mv = np.asarray(vehicle_xy, np.float64)
    if mv.ndim != 2 or mv.shape[1] != 2:
        raise BackendError(f"vehicle_xy must have shape (B, 2), got {mv.shape}")
    B = mv.shape[0]
    mt = np.asarray(threat_xy, np.float64)
    if mt.shape != (B, 2):
        raise BackendError(f"threat_xy must have shape ({B}, 2), got {mt.shape}")
    av = compass_to_math_rad(_per_pair(vehicle_heading_deg, "vehicle_heading_deg", B, ()))
    at = compass_to_math_rad(_per_pair(threat_heading_deg, "threat_heading_deg", B, ()))
    sv = _per_pair(vehicle_size, "vehicle_size", B, (2,))
    st = _per_pair(threat_size, "threat_size", B, (2,))
    cv = _per_pair(vehicle_cov, "vehicle_cov", B, (2, 2))
    ct = _per_pair(threat_cov, "threat_cov", B, (2, 2))
    row, why, hh, slope, share, sign = k.edge_terms(mv, mt, av, at, sv, st, cv, ct)
    if why:
        raise BackendError(f"{_PAIR_ERRORS[why]} (row {row})")
    g = share - owens_t(hh, slope)
    mass = (sign * (g[:, 8:] - g[:, :8])).sum(axis=1)
    p: Array = np.minimum(np.maximum(mass, 0.0), 1.0)
    return p


_PAIR_ERRORS = {
    1: "vehicle and threat positions and headings must be finite",
    2: "vehicle_size must be (length_m, width_m) ≥ 0",
    3: "threat_size must be (length_m, width_m) ≥ 0",
    4: "vehicle_cov must be finite",
    5: "vehicle_cov must be a symmetric positive semi-definite 2×2 matrix",
    6: "threat_cov must be finite",
    7: "threat_cov must be a symmetric positive semi-definite 2×2 matrix",
}
"""What :func:`~rfsas_hw.backend._collision_kernel.pair_error`'s codes mean."""


def _per_pair(value: Any, name: str, B: int, shape: tuple[int, ...]) -> Array:
    """``value`` as ``B`` rows of ``shape``, or one row for every pair: shape (B or 1, *shape).

    Raises:
        BackendError: another shape.
    """
    arr = np.asarray(value, np.float64)
    if arr.shape == shape:
        return arr[None]
    if arr.shape != (B, *shape):
        raise BackendError(f"{name} must have shape {shape} or {(B, *shape)}, got {arr.shape}")
    return np.ascontiguousarray(arr)


@dataclass(frozen=True, slots=True)
class MonteCarloEstimate:
    """A Monte Carlo probability with its standard error."""

    p: float
    """Fraction of samples whose boxes overlap."""
    stderr: float
    """Binomial standard error ``√(p(1−p)/n)``."""
    n: int
    """Number of samples."""


def _sqrt_cov(cov: Array) -> Array:
    """A factor ``F`` with ``F Fᵀ = cov`` that also works for semi-definite covariances."""
    w, v = np.linalg.eigh(cov)
    return np.asarray(v * np.sqrt(np.maximum(w, 0.0)), np.float64)


def _project(axes_u: Array, axes_n: Array, half: Size, k: Array) -> Array:
    """Half-extent of a box with axes (u, n) and half sizes ``half`` projected on ``k``."""
    return np.asarray(
        half[0] * np.abs(np.sum(axes_u * k, axis=-1))
        + half[1] * np.abs(np.sum(axes_n * k, axis=-1)),
        np.float64,
    )


def collision_probability_mc(
    vehicle_xy: Any,
    vehicle_heading_deg: float,
    vehicle_cov: Any,
    vehicle_size: Any,
    threat_xy: Any,
    threat_heading_deg: float,
    threat_cov: Any,
    threat_size: Any,
    n: int = 100_000,
    seed: int | np.random.Generator | None = None,
    *,
    vehicle_heading_sigma_deg: float = 0.0,
    threat_heading_sigma_deg: float = 0.0,
    chunk: int = 65_536,
) -> MonteCarloEstimate:
    """Lambert's Monte Carlo: sample both boxes, count separating-axis overlaps.

    Arguments as :func:`collision_probability` (one pair), plus optional
    one-sigma heading errors (degrees) that the exact method cannot handle.
    Samples are drawn in chunks of ``chunk`` to bound memory.

    Raises:
        BackendError: invalid inputs or ``n < 1``.
    """
    if n < 1:
        raise BackendError(f"Monte Carlo needs n ≥ 1 samples, got {n}")
    if vehicle_heading_sigma_deg < 0 or threat_heading_sigma_deg < 0:
        raise BackendError("heading sigmas must be ≥ 0 degrees")
    mv, mt = _point(vehicle_xy, "vehicle_xy"), _point(threat_xy, "threat_xy")
    sv = _size(VEHICLE_SIZE if vehicle_size is None else vehicle_size, "vehicle_size")
    st = threat_box(threat_size)
    cv = _cov(
        heading_covariance(vehicle_heading_deg) if vehicle_cov is None else vehicle_cov,
        "vehicle_cov",
        (),
    )
    ct = _cov(threat_cov, "threat_cov", ())
    fv, ft = _sqrt_cov(cv), _sqrt_cov(ct)
    hv_half = (sv[0] / 2, sv[1] / 2)
    ht_half = (st[0] / 2, st[1] / 2)
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    uv0, nv0 = _axes(np.array(vehicle_heading_deg))
    ut0, nt0 = _axes(np.array(threat_heading_deg))
    axes_k = np.stack([uv0, nv0, ut0, nt0])
    reach_k = _project(uv0, nv0, hv_half, axes_k) + _project(ut0, nt0, ht_half, axes_k)
    # with fixed headings the centre offset projected on the four axes is linear
    # in the four normals: proj = offset + coeff @ z, one small matrix product
    coeff = np.concatenate([-(axes_k @ fv), axes_k @ ft], axis=1)
    offset = axes_k @ (mt - mv)
    fixed_headings = vehicle_heading_sigma_deg == 0 and threat_heading_sigma_deg == 0
    hits = 0
    done = 0
    while done < n:
        m = min(chunk, n - done)
        z = rng.standard_normal((4, m))
        if fixed_headings:
            proj = coeff @ z
            proj += offset[:, None]
            overlap = np.all(np.abs(proj) <= reach_k[:, None], axis=0)
        else:
            d = (mt - mv) + (ft @ z[2:] - fv @ z[:2]).T
            e = rng.standard_normal((m, 2))
            uv, nv = _axes(vehicle_heading_deg + vehicle_heading_sigma_deg * e[:, 0])
            ut, nt = _axes(threat_heading_deg + threat_heading_sigma_deg * e[:, 1])
            overlap = np.ones(m, bool)
            for k in (uv, nv, ut, nt):
                reach = _project(uv, nv, hv_half, k) + _project(ut, nt, ht_half, k)
                overlap &= np.abs(np.sum(d * k, axis=-1)) <= reach
        hits += int(np.count_nonzero(overlap))
        done += m
    p = hits / n
    return MonteCarloEstimate(p=p, stderr=math.sqrt(p * (1 - p) / n), n=n)


def _point(value: Any, name: str) -> Array:
    arr = np.asarray(value, np.float64)
    if arr.shape != (2,) or not np.all(np.isfinite(arr)):
        raise BackendError(f"{name} must be a finite (x_m, y_m) pair, got {value!r}")
    return arr


def collision_probability(
    vehicle_xy: Any,
    vehicle_heading_deg: float,
    vehicle_cov: Any,
    vehicle_size: Any,
    threat_xy: Any,
    threat_heading_deg: float,
    threat_cov: Any,
    threat_size: Any,
    method: Literal["exact", "montecarlo"] = "exact",
    n: int = 100_000,
    seed: int | np.random.Generator | None = None,
) -> float:
    """Probability that the vehicle's box and the threat's box overlap.

    Args:
        vehicle_xy: vehicle centre ``(x_m, y_m)``, metres east/north.
        vehicle_heading_deg: vehicle heading, compass degrees.
        vehicle_cov: 2×2 vehicle position covariance, m²; None for the default
            3 m along-track / 1 m cross-track.
        vehicle_size: ``(length_m, width_m)``; None for 4.5 × 1.8 m.
        threat_xy: threat centre ``(x_m, y_m)``, metres.
        threat_heading_deg: threat heading, compass degrees (irrelevant for a square box).
        threat_cov: 2×2 threat position covariance, m² (e.g. a fix's covariance).
        threat_size: ``(length_m, width_m)`` or a kind: ``pedestrian``,
            ``cyclist``, ``vehicle``.
        method: ``exact`` (Owen's T over the Minkowski sum) or ``montecarlo``
            (Lambert's separating-axis sampling).
        n: Monte Carlo samples (ignored by ``exact``).
        seed: Monte Carlo seed or generator (ignored by ``exact``).

    Returns:
        The probability, in [0, 1].

    Raises:
        BackendError: invalid inputs or an unknown method.
    """
    if method == "montecarlo":
        return collision_probability_mc(
            vehicle_xy,
            vehicle_heading_deg,
            vehicle_cov,
            vehicle_size,
            threat_xy,
            threat_heading_deg,
            threat_cov,
            threat_size,
            n=n,
            seed=seed,
        ).p
    if method != "exact":
        raise BackendError(f"unknown collision method {method!r}; use 'exact' or 'montecarlo'")
    pair = "an (x_m, y_m) pair"
    cv = heading_covariance(vehicle_heading_deg) if vehicle_cov is None else vehicle_cov
    size = "(length_m, width_m)"
    sv = VEHICLE_SIZE if vehicle_size is None else vehicle_size
    p = collision_probability_batch(
        _shaped(vehicle_xy, "vehicle_xy", (2,), pair)[None],
        _shaped(vehicle_heading_deg, "vehicle_heading_deg", (), "one number"),
        _shaped(cv, "vehicle_cov", (2, 2), "a 2×2 covariance in m²")[None],
        _shaped(sv, "vehicle_size", (2,), size),
        _shaped(threat_xy, "threat_xy", (2,), pair)[None],
        _shaped(threat_heading_deg, "threat_heading_deg", (), "one number"),
        _shaped(threat_cov, "threat_cov", (2, 2), "a 2×2 covariance in m²")[None],
        threat_box(threat_size) if isinstance(threat_size, str) else threat_size,
    )
    return float(p[0])
