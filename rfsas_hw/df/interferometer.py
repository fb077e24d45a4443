"""Phase interferometer: bearings from the CSI phase difference of two antennas.

Geometry and sign: antennas ``a`` and ``b`` sit on a baseline of length ``D``
(metres) with ``b`` on the clockwise side of ``a``. A plane wave from θ
(degrees clockwise from boresight) reaches ``b`` first, so the channel phase
difference is ::

    Δφ = arg(h_b·conj(h_a)) = 2π·(D/λ)·sin θ + φ_cal        (mod 2π)

with ``φ_cal`` the pair's calibrated offset (cables, chains, the board).

Per frame:

1. The sampling-time offset (a linear phase across subcarriers, common to
   every antenna) cancels in ``h_b·conj(h_a)`` (its ramp has unit
   magnitude), so the pair needs no STO removal; :func:`remove_sto` is for
   per-antenna phases. A delay between the pair's chains does not cancel:
   the calibration's ``delay_ns`` removes it.
2. ``z_k = h_b,k·conj(h_a,k)`` over subcarriers and streams; the frame's
   phase is ``arg Σ z_k`` minus ``φ_cal``, and its measured spread is the
   magnitude-weighted RMS of ``arg z_k`` about that mean divided by ``√N``
   (N terms).
3. ``sin θ = (Δφ + 2πm)·λ/(2πD)``: for ``D ≤ λ/2`` one branch ``m`` fits;
   above, several do and the branch nearest a hint (the amplitude monopulse
   angle — the hybrid) or, without one, nearest boresight is chosen. The
   choice is kept when its probability under a Gaussian hint error (the
   hint's σ) is at least ``min_branch_probability`` (0.999), else — and
   always without a hint — the frame is flagged ``AMBIGUOUS``.
4. σ: the method's formula with the pair's effective SNR
   ``N·2/(1/SNR_a + 1/SNR_b)`` (the Cramér–Rao bound of the phase
   difference when the common channel is unknown: var Δφ = 1/(N·SNR)),
   against the measured spread — the larger wins — plus the calibration's
   residual, all through ``dθ = dΔφ / (2π·(D/λ)·cos θ)``. The textbook form
   is the default here because it is the CRB; ``form="published"`` uses the
   method's published form, 2π larger (method.md §3).

Angles outside ``fov_deg`` are flagged ``OUTSIDE_FOV``.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.records import CsiBlock
from rfsas_hw.rf.aoa import PhaseForm

Array = npt.NDArray[np.float64]
C_MPS = 299_792_458.0
SUBCARRIER_SPACING_HZ = 312_500.0


class IfFlag(enum.IntFlag):
    """Why an interferometer bearing is not valid (0 = valid)."""

    NONE = 0
    MISSING_CHAIN = 0x01
    """An antenna of the pair carried no CSI in this frame."""
    OUTSIDE_FOV = 0x04
    """The angle is outside the field of view."""
    NO_TABLE = 0x08
    """No phase calibration for the frame's channel, or no frequency."""
    AMBIGUOUS = 0x20
    """More than one branch fits (D > λ/2) and nothing decides between them."""


def remove_sto(
    h: npt.NDArray[np.complex64], subcarrier: npt.ArrayLike
) -> npt.NDArray[np.complex64]:
    """Remove each frame's linear phase across subcarriers (sampling-time offset).

    The slope is the phase of ``Σ h_{k+1}·conj(h_k)`` over neighbouring
    columns at the most common index step, summed over antennas and streams
    (so it is common to all antennas and their differences are untouched).

    Args:
        h: CSI, shape (n, n_rx, n_tx, n_sc), NaN where absent.
        subcarrier: index of each column.
    """
    sub = np.asarray(subcarrier, np.int64)
    if h.shape[-1] < 2:
        return h
    steps = np.diff(sub)
    step = int(np.bincount(np.abs(steps)).argmax()) or 1
    pick = np.flatnonzero(steps == step)
    clean = np.where(np.isfinite(h), h, 0)
    prod = clean[..., pick + 1] * np.conj(clean[..., pick])
    slope = np.angle(prod.sum(axis=(1, 2, 3))) / step  # rad per subcarrier index
    ramp = np.exp(-1j * slope[:, None] * sub[None, :]).astype(np.complex64)
    out: npt.NDArray[np.complex64] = (h * ramp[:, None, None, :]).astype(np.complex64)
    return out


@dataclass(frozen=True, slots=True)
class PairPhase:
    """Per-frame phase difference of one antenna pair."""

    phase_rad: Array
    """arg Σ h_b·conj(h_a) minus the calibration offset, wrapped to (−π, π]; NaN if missing."""
    spread_rad: Array
    """Measured one-sigma of ``phase_rad``: RMS per-term deviation / √N, rad."""
    terms: npt.NDArray[np.int64]
    """Subcarrier × stream terms used."""


def pair_phase(
    csi: CsiBlock,
    a: int = 0,
    b: int = 1,
    *,
    offset_rad: npt.ArrayLike = 0.0,
    delay_ns: npt.ArrayLike = 0.0,
) -> PairPhase:
    """Phase of antenna ``b`` relative to ``a`` per frame, after calibration removal.

    ``offset_rad`` and ``delay_ns`` (chain b's extra delay, giving a phase
    ``2π·Δf·k·delay`` across subcarriers) may be scalars or per-frame arrays.

    Raises:
        ValueError: ``a`` or ``b`` is not an antenna of the block.
    """
    n_rx = csi.h.shape[1]
    if not (0 <= a < n_rx and 0 <= b < n_rx and a != b):
        raise ValueError(f"antenna pair ({a}, {b}) not in a block of {n_rx} antennas")
    sub = csi.subcarrier.astype(np.float64)
    # the common sampling-time offset cancels in this product: no remove_sto
    z = csi.h[:, b] * np.conj(csi.h[:, a])  # (n, n_tx, n_sc)
    delay = np.broadcast_to(np.asarray(delay_ns, np.float64), (len(csi),))
    if np.any(delay != 0):
        turn = 2 * math.pi * SUBCARRIER_SPACING_HZ * 1e-9 * delay[:, None] * sub[None, :]
        z = z * np.exp(-1j * turn)[:, None, :]
    ok = np.isfinite(z) & (z != 0)
    z = np.where(ok, z, 0)
    total = z.sum(axis=(1, 2))
    terms = ok.sum(axis=(1, 2)).astype(np.int64)
    mean = np.angle(total)
    dev = np.angle(z * np.exp(-1j * mean)[:, None, None])
    w = np.abs(z)
    wsum = w.sum(axis=(1, 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt((w * dev**2).sum(axis=(1, 2)) / wsum)
        spread = rms / np.sqrt(terms)
    offset = np.broadcast_to(np.asarray(offset_rad, np.float64), (len(csi),))
    phase = np.angle(np.exp(1j * (mean - offset)))
    missing = terms == 0
    phase = np.where(missing, np.nan, phase)
    spread = np.where(missing, np.nan, spread)
    return PairPhase(phase.astype(np.float64), spread.astype(np.float64), terms)


@dataclass(frozen=True, slots=True)
class InterferometerResult:
    """Per-frame interferometer bearings (arrays of one length)."""

    angle_deg: Array
    """Angle from boresight, degrees clockwise; NaN where invalid."""
    sigma_deg: Array
    """One-sigma angle error, degrees; NaN where invalid."""
    branch: npt.NDArray[np.int64]
    """Chosen phase branch m (0 for D ≤ λ/2)."""
    candidates: npt.NDArray[np.int64]
    """Branches that fit inside the field of view."""
    flags: npt.NDArray[np.uint8]
    """:class:`IfFlag` bits; 0 where valid."""

    @property
    def valid(self) -> npt.NDArray[np.bool_]:
        """True where the bearing can be used."""
        out: npt.NDArray[np.bool_] = self.flags == 0
        return out


def effective_snr_db(
    snr_a_db: npt.ArrayLike, snr_b_db: npt.ArrayLike, terms: npt.ArrayLike
) -> Array:
    """SNR of the summed pair product: ``N · 2/(1/SNR_a + 1/SNR_b)``, dB."""
    sa = np.power(10.0, np.asarray(snr_a_db, np.float64) / 10.0)
    sb = np.power(10.0, np.asarray(snr_b_db, np.float64) / 10.0)
    n = np.maximum(np.asarray(terms, np.float64), 1.0)
    out: Array = 10.0 * np.log10(n * 2.0 / (1.0 / sa + 1.0 / sb))
    return out


def bearings(
    phase: PairPhase,
    freq_mhz: npt.ArrayLike,
    baseline_m: float,
    *,
    snr_db: npt.ArrayLike | None = None,
    residual_deg: npt.ArrayLike = 0.0,
    fov_deg: tuple[float, float] = (-60.0, 60.0),
    hint_deg: npt.ArrayLike | None = None,
    hint_sigma_deg: npt.ArrayLike | None = None,
    min_branch_probability: float = 0.999,
    form: PhaseForm = "textbook",
) -> InterferometerResult:
    """Angles and σ from pair phases (see the module text).

    Args:
        phase: from :func:`pair_phase`.
        freq_mhz: centre frequency per frame (or one), MHz; 0 → ``NO_TABLE``.
        baseline_m: antenna spacing D, metres.
        snr_db: effective SNR of the pair product per frame (:func:`effective_snr_db`);
            None: σ from the measured spread alone.
        residual_deg: the calibration's phase residual (one sigma, degrees of Δφ).
        fov_deg: field of view (lower, upper), degrees from boresight.
        hint_deg, hint_sigma_deg: an independent angle per frame (monopulse) and its σ;
            NaN where none. Used only to choose a branch.
        min_branch_probability: when several branches fit, the chosen one must be at
            least this probable under a Gaussian hint error (σ = hint σ), else ``AMBIGUOUS``.
        form: ``textbook`` (the CRB) or ``published`` (2π larger) σ formula.

    Raises:
        ValueError: ``baseline_m`` not positive, or an unknown ``form``.
    """
    if not baseline_m > 0:
        raise ValueError(f"baseline must be positive, got {baseline_m}")
    if form not in ("textbook", "published"):
        raise ValueError(f"unknown form {form!r}: use published or textbook")
    dphi = phase.phase_rad
    n = len(dphi)
    freq = np.broadcast_to(np.asarray(freq_mhz, np.float64), (n,))
    flags = np.zeros(n, np.uint8)
    flags[~np.isfinite(dphi)] |= np.uint8(IfFlag.MISSING_CHAIN)
    flags[~(freq > 0)] |= np.uint8(IfFlag.NO_TABLE)
    with np.errstate(invalid="ignore", divide="ignore"):
        lam = C_MPS / (freq * 1e6)
        ratio = baseline_m / lam  # D/λ
        u0 = dphi / (2 * math.pi * ratio)
    m_max = math.ceil(2 * baseline_m / float(np.nanmin(lam))) + 1 if np.any(freq > 0) else 1
    ms = np.arange(-m_max, m_max + 1)
    lo, hi = fov_deg
    with np.errstate(invalid="ignore", divide="ignore"):
        u = u0[:, None] + ms[None, :] / ratio[:, None]
        theta = np.degrees(np.arcsin(np.clip(u, -1.0, 1.0)))
        fits = (np.abs(u) <= 1.0) & (theta >= lo) & (theta <= hi)
    count = fits.sum(axis=1)
    if hint_deg is None:
        target = np.zeros(n)
        tsig = np.full(n, np.nan)
    else:
        target = np.broadcast_to(np.asarray(hint_deg, np.float64), (n,)).copy()
        tsig = np.broadcast_to(
            np.asarray(np.nan if hint_sigma_deg is None else hint_sigma_deg, np.float64), (n,)
        ).copy()
        no_hint = ~np.isfinite(target)
        target[no_hint] = 0.0
        tsig[no_hint] = np.nan
    dist = np.where(fits, np.abs(theta - target[:, None]), np.inf)
    order = np.argsort(dist, axis=1)
    best = order[:, 0]
    rows = np.arange(n)
    angle = theta[rows, best]
    branch = ms[best]
    if dist.shape[1] > 1:
        # probability of the chosen branch under a Gaussian hint error
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            excess = (dist**2 - dist[rows, best][:, None] ** 2) / (2 * tsig[:, None] ** 2)
            p_best = 1.0 / np.sum(np.where(np.isfinite(dist), np.exp(-excess), 0.0), axis=1)
        sure = np.isfinite(p_best) & (p_best >= min_branch_probability)
        flags[(count > 1) & ~sure] |= np.uint8(IfFlag.AMBIGUOUS)
    flags[(count == 0) & (flags == 0)] |= np.uint8(IfFlag.OUTSIDE_FOV)
    # σ through the slope dΔφ/dθ = 2π·(D/λ)·cos θ
    cos = np.cos(np.radians(np.clip(angle, -89.9, 89.9)))
    with np.errstate(invalid="ignore", divide="ignore"):
        per_rad = 1.0 / (2 * math.pi * ratio * cos)  # rad of θ per rad of Δφ
        scale = 2 * math.pi if form == "published" else 1.0
        if snr_db is None:
            formula = np.zeros(n)
        else:
            snr = np.power(10.0, np.broadcast_to(np.asarray(snr_db, np.float64), (n,)) / 10.0)
            formula = scale / np.sqrt(snr)
        formula = np.where(np.isfinite(formula), formula, 0.0)
        spread = np.where(np.isfinite(phase.spread_rad), phase.spread_rad, 0.0)
        resid = np.radians(np.broadcast_to(np.asarray(residual_deg, np.float64), (n,)))
        var = np.maximum(formula, spread) ** 2 + resid**2
        sigma = np.degrees(np.sqrt(var) * per_rad)
    bad = flags != 0
    angle = np.where(bad, np.nan, angle)
    sigma = np.where(bad, np.nan, sigma)
    return InterferometerResult(
        angle.astype(np.float64),
        sigma.astype(np.float64),
        branch.astype(np.int64),
        count.astype(np.int64),
        flags,
    )


def geometric_phase_rad(
    theta_deg: npt.ArrayLike, freq_mhz: npt.ArrayLike, baseline_m: float
) -> Any:
    """The phase difference ``2π·(D/λ)·sin θ`` of a plane wave from θ (not wrapped), rad."""
    lam = C_MPS / (np.asarray(freq_mhz, np.float64) * 1e6)
    return 2 * math.pi * baseline_m / lam * np.sin(np.radians(np.asarray(theta_deg, np.float64)))
