"""Bearings from all elements of an array at once: the maximum-likelihood plane-wave fit.

For one emitter, snapshots ``x_s`` (one complex sample per element) are
modelled as ``x_s = c_s·a(θ) + n_s`` with an unknown complex amplitude
``c_s`` per snapshot and white noise. The maximum-likelihood θ maximises
the fraction of the packet's power one plane wave explains ::

    ρ(θ) = Σ_s |a(θ)ᴴ x_s|² / (N · Σ_s ‖x_s‖²)        (0 … 1)

(a least-squares fit over every element; for one source it is the
Bartlett beam's peak). θ is searched on a grid over the full circle — or,
for a collinear array (which cannot tell front from back), over the half
plane in front of it — and refined by golden-section search to 0.001°.

σ is the Cramér–Rao bound at the estimate with the noise measured from the
fit's own residual, ``σ̂² = (1 − ρ)·Σ‖x_s‖² / (S·(N−1) − ½)`` (the fit
spends one complex amplitude per snapshot and one real angle), plus the
element calibration's measured phase residual ``σ_c`` ::

    var θ = σ̂²·N / (2·P·h) + σ_c² / (2·h),   P = Σ_s |aᴴx_s|² / N,
    h = ‖ȧ‖² − |aᴴȧ|²/N                          (ȧ = da/dθ, rad⁻¹)

A packet whose second-highest peak of ρ reaches ``ambiguity_ratio`` of the
highest (multipath, or a mirror that the geometry cannot resolve), or whose
residual is far above a known noise power (multipath too close to show a
second peak), is flagged ``AMBIGUOUS`` instead of guessing; one outside ``fov_deg`` is flagged
``OUTSIDE_FOV``; the edge rule of :mod:`rfsas_hw.df.fovrule` applies when a
field of view narrower than the search is given.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.df.array import ArrayGeometry
from rfsas_hw.df.arraycal import ElementCalibration
from rfsas_hw.df.estimate import DfFlag, DfResult
from rfsas_hw.df.fovrule import near_edge

Array = npt.NDArray[np.floating[Any]]
Complex = npt.NDArray[np.complexfloating[Any, Any]]

GRID_STEP_DEG = 1.0
"""Search grid before refinement, degrees (finer than any array's beam here)."""
MISFIT_RATIO = 4.0
"""With a known noise power, a residual this many times larger flags the packet
``AMBIGUOUS``: more than one wave (unresolved multipath) is in it."""
AMBIGUITY_RATIO = 0.6
"""A second peak of ρ at least this fraction of the first flags the packet ``AMBIGUOUS``."""
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


def fit_element_calibration(
    geometry: ArrayGeometry,
    snapshots: npt.ArrayLike,
    theta_deg: npt.ArrayLike,
    freq_mhz: float,
) -> ElementCalibration:
    """Per-element phase and gain from packets of a transmitter at known angles (a
    turntable or a known position), shape (packets, snapshots, N) or (packets, N).

    Each element's channel is compared with element 0's after removing the
    plane-wave phase of the known angle; the offsets are the circular mean
    over all snapshots, the residual the spread about it (÷√2: the
    difference of two elements' noise).

    Raises:
        ValueError: shapes that do not match the geometry or the angles.
    """
    x = _as_snapshots(snapshots, geometry.n)
    theta = np.broadcast_to(np.asarray(theta_deg, np.float64), (len(x),))
    a = geometry.steering(theta, freq_mhz)[:, None, :]
    z = x * np.conj(a)
    rel = z * np.conj(z[..., :1])
    phase = np.angle(rel.reshape(-1, geometry.n).sum(axis=0))
    phase[0] = 0.0
    power = np.mean(np.abs(z) ** 2, axis=(0, 1))
    gain = 10.0 * np.log10(np.maximum(power, 1e-300) / max(float(power[0]), 1e-300))
    dev = np.angle(rel[..., 1:] * np.exp(-1j * phase[1:]))
    residual = float(np.sqrt(np.mean(dev**2) / 2.0)) if dev.size else 0.0
    return ElementCalibration(phase, gain, residual)


def _as_snapshots(snapshots: npt.ArrayLike, n_el: int) -> npt.NDArray[np.complex128]:
    x = np.asarray(snapshots, np.complex128)
    if x.ndim == 2:
        x = x[:, None, :]
    if x.ndim != 3 or x.shape[-1] != n_el:
        raise ValueError(f"snapshots must be (packets, [snapshots,] {n_el}), got {x.shape}")
    return x


@dataclass(frozen=True, slots=True)
class ArrayResult:
    """Per-packet results of :func:`estimate_array` (arrays of one length)."""

    df: DfResult
    """Angle (degrees clockwise from boresight, full circle in (−180, 180]), σ, SNR
    per element and snapshot (dB) and flags, in the shape every DF method returns."""
    fit: Array
    """ρ at the estimate: the share of the packet's power one plane wave explains."""
    second_peak: Array
    """Second-highest peak of ρ divided by the highest (0 when there is none)."""
    crb_deg: Array = field(default_factory=lambda: np.zeros(0))
    """The Cramér–Rao part of σ (without the calibration residual), degrees."""


def _search_range(geometry: ArrayGeometry) -> tuple[float, float, bool]:
    """(lower, upper, circular) search interval, degrees."""
    if not geometry.collinear:
        return -180.0, 180.0, True
    normal = (geometry.axis_deg - 90.0 + 180.0) % 180.0  # in [0, 180)
    if normal > 90.0:
        normal -= 180.0  # the normal nearest boresight, in (−90, 90]
    return normal - 90.0, normal + 90.0, False


def _power_share(proj: Complex, x: Complex, n_el: int) -> Array:
    """Σ_s |projection|² / (N · Σ_s ‖x_s‖²), over the snapshot axis 1."""
    total = np.sum(np.abs(x) ** 2, axis=(1, 2))
    scale = 1.0 / (n_el * np.maximum(total, 1e-300))
    out: Array = np.sum(np.abs(proj) ** 2, axis=1) * scale.reshape((-1,) + (1,) * (proj.ndim - 2))
    return out


def _rho_grid(geometry: ArrayGeometry, x: Complex, grid_deg: Array, freq_mhz: float) -> Array:
    """ρ of every packet at every grid angle, (n, G)."""
    a = np.conj(geometry.steering(grid_deg, freq_mhz))  # (G, N)
    return _power_share(x @ a.T, x, geometry.n)  # x @ aᴴ: (n, S, G)


def _rho_at(geometry: ArrayGeometry, x: Complex, theta_deg: Array, freq_mhz: float) -> Array:
    """ρ of each packet at its own angle, (n,)."""
    a = np.conj(geometry.steering(theta_deg, freq_mhz))  # (n, N)
    return _power_share(np.einsum("nk,nsk->ns", a, x), x, geometry.n)


def estimate_array(
    geometry: ArrayGeometry,
    snapshots: npt.ArrayLike,
    freq_mhz: float,
    *,
    calibration: ElementCalibration | None = None,
    fov_deg: tuple[float, float] | None = None,
    grid_step_deg: float = GRID_STEP_DEG,
    ambiguity_ratio: float = AMBIGUITY_RATIO,
    noise_power: float | None = None,
) -> ArrayResult:
    """Angle, σ and flags of each packet from all elements (see the module text).

    Args:
        geometry: the array.
        snapshots: complex samples, (packets, snapshots, N) or (packets, N); NaN marks
            a missing element (the packet is flagged ``MISSING_CHAIN``).
        freq_mhz: carrier frequency, MHz.
        calibration: per-element phase/gain to remove first, and its residual.
        fov_deg: angles outside are flagged ``OUTSIDE_FOV``, and bearings whose ±3σ
            leaves it ``MAY_BE_OUTSIDE``; None: the whole search range.
        grid_step_deg: search grid before refinement, degrees.
        ambiguity_ratio: second/first peak of ρ from which a packet is ``AMBIGUOUS``.
        noise_power: the receiver's noise power per element and snapshot, in the
            samples' units squared, when known; a fit residual over
            :data:`MISFIT_RATIO` times it flags the packet ``AMBIGUOUS`` (multipath
            too close to resolve biases the angle without a second peak).

    Raises:
        ValueError: shapes that do not match, a frequency that is not positive.
    """
    if not freq_mhz > 0:
        raise ValueError(f"frequency must be positive, got {freq_mhz} MHz")
    x = _as_snapshots(snapshots, geometry.n)
    if calibration is not None:
        x = calibration.apply(x)
    n, s, n_el = x.shape
    missing = ~np.all(np.isfinite(x), axis=(1, 2))
    x = np.where(np.isfinite(x), x, 0.0)
    lo, hi, circular = _search_range(geometry)
    grid = np.arange(lo, hi + (0.0 if circular else 1e-9), grid_step_deg)
    g = len(grid)
    rho = _rho_grid(geometry, x, grid, freq_mhz)
    best = np.argmax(rho, axis=1) if n else np.zeros(0, np.intp)
    # second peak: the highest local maximum other than the main one
    left = np.roll(rho, 1, axis=1)
    right = np.roll(rho, -1, axis=1)
    if not circular:  # an end of the range is a lobe's tail, not a peak of its own
        left[:, 0] = np.inf
        right[:, -1] = np.inf
    peaks = (rho >= left) & (rho >= right)
    rows = np.arange(n)
    near = np.abs(np.arange(g)[None, :] - best[:, None])
    if circular:
        near = np.minimum(near, g - near)
    peaks &= near > 1
    second = np.where(peaks, rho, 0.0).max(axis=1, initial=0.0) if n else np.zeros(0)
    top = rho[rows, best] if n else np.zeros(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(top > 0, second / top, 0.0)
    # golden-section refinement within one grid step of the peak
    a_lo = grid[best] - grid_step_deg
    a_hi = grid[best] + grid_step_deg
    if not circular:
        a_lo, a_hi = np.maximum(a_lo, lo), np.minimum(a_hi, hi)
    c = a_hi - _GOLDEN * (a_hi - a_lo)
    d = a_lo + _GOLDEN * (a_hi - a_lo)
    fc = _rho_at(geometry, x, c, freq_mhz)
    fd = _rho_at(geometry, x, d, freq_mhz)
    for _ in range(40):  # the bracket shrinks to 0.618⁴⁰ of two grid steps
        lb = fc > fd  # the maximum lies in [a_lo, d]
        a_hi = np.where(lb, d, a_hi)
        a_lo = np.where(lb, a_lo, c)
        probe = np.where(lb, a_hi - _GOLDEN * (a_hi - a_lo), a_lo + _GOLDEN * (a_hi - a_lo))
        fp = _rho_at(geometry, x, probe, freq_mhz)
        c, d = np.where(lb, probe, d), np.where(lb, c, probe)
        fc, fd = np.where(lb, fp, fd), np.where(lb, fc, fp)
    theta = (0.5 * (a_lo + a_hi) + 180.0) % 360.0 - 180.0
    fit = _rho_at(geometry, x, theta, freq_mhz)
    # σ: the CRB with the noise measured from the fit's residual
    total = np.sum(np.abs(x) ** 2, axis=(1, 2))
    power = fit * total  # Σ_s |aᴴx_s|² / N
    noise = np.maximum(total - power, 0.0) / (s * (n_el - 1) - 0.5)
    a = geometry.steering(theta, freq_mhz)
    da = geometry.steering_derivative(theta, freq_mhz)
    h = np.sum(np.abs(da) ** 2, axis=1) - np.abs(np.sum(np.conj(a) * da, axis=1)) ** 2 / n_el
    with np.errstate(invalid="ignore", divide="ignore"):
        var_crb = noise * n_el / (2.0 * power * h)
        resid = 0.0 if calibration is None else calibration.residual_rad
        var = var_crb + resid**2 / (2.0 * h)
        snr_db = 10.0 * np.log10(power / (s * n_el) / noise)
    sigma = np.degrees(np.sqrt(var))
    flags = missing.view(np.uint8) * np.uint8(DfFlag.MISSING_CHAIN)
    ambiguous = ratio >= ambiguity_ratio
    if noise_power is not None:
        ambiguous |= noise > MISFIT_RATIO * noise_power
    flags |= ambiguous.view(np.uint8) * np.uint8(DfFlag.AMBIGUOUS)
    flags |= (~np.isfinite(sigma) & ~missing).view(np.uint8) * np.uint8(DfFlag.LOW_SNR)
    if fov_deg is not None:
        f_lo, f_hi = fov_deg
        outside = (theta < f_lo) | (theta > f_hi)
        flags |= outside.view(np.uint8) * np.uint8(DfFlag.OUTSIDE_FOV)
        edge = near_edge(theta, sigma, fov_deg) & ~outside
        flags |= edge.view(np.uint8) * np.uint8(DfFlag.MAY_BE_OUTSIDE)
    bad = flags != 0
    angle = np.where(bad, np.nan, theta)
    sigma_out = np.where(bad, np.nan, sigma)
    return ArrayResult(
        DfResult(angle, sigma_out, np.asarray(snr_db, np.float64), flags),
        fit,
        ratio,
        np.degrees(np.sqrt(var_crb)),
    )


def crb_deg(
    geometry: ArrayGeometry, theta_deg: npt.ArrayLike, snr_db: npt.ArrayLike, freq_mhz: float,
    snapshots: int = 1,
) -> Array:  # fmt: skip
    """The Cramér–Rao bound of θ for one plane wave of known SNR per element and
    snapshot (dB), degrees: ``√(1 / (2·S·SNR·h(θ)))``."""
    theta = np.asarray(theta_deg, np.float64)
    a = geometry.steering(theta, freq_mhz)
    da = geometry.steering_derivative(theta, freq_mhz)
    h = (
        np.sum(np.abs(da) ** 2, axis=-1)
        - np.abs(np.sum(np.conj(a) * da, axis=-1)) ** 2 / geometry.n
    )
    snr = 10.0 ** (np.asarray(snr_db, np.float64) / 10.0)
    out: Array = np.degrees(np.sqrt(1.0 / (2.0 * snapshots * snr * h)))
    return out
