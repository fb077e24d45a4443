"""Angle-of-arrival error of the two DF methods (method.md §3).

Phase interferometer: ``σ = 1 / ((D/λ)·cos θ·√SNR)`` rad (the published form).
The textbook Cramér–Rao form carries a further ``2π`` in the denominator,
``σ = 1 / (2π·(D/λ)·cos θ·√SNR)``; choose it with ``form="textbook"``. The
published numbers (σ = 1.2285° at 27 dB) use the first form.

Amplitude monopulse: ``σ = β / (k_m·√SNR)`` with beamwidth β and the
normalised slope ``k_m = 1.386`` of a Gaussian beam at its 3 dB point.
SNR is linear inside the formulas; the functions take dB.
"""

from __future__ import annotations

import math
from typing import Any, Literal

import numpy as np

PhaseForm = Literal["published", "textbook"]


def db_to_linear(db: Any) -> Any:
    """Power ratio from dB (float or array)."""
    return np.power(10.0, np.asarray(db, dtype=np.float64) / 10.0)


def sigma_phase_deg(
    snr_db: Any,
    theta_deg: Any = 0.0,
    *,
    baseline_m: float = 0.25,
    wavelength_m: float = 0.12,
    form: PhaseForm = "published",
) -> Any:
    """One-sigma angle error of a two-element phase interferometer, degrees.

    Raises:
        ValueError: unknown ``form``, or |θ| ≥ 90° (no resolution along the baseline).
    """
    theta = np.deg2rad(np.asarray(theta_deg, dtype=np.float64))
    if np.any(np.abs(theta) >= math.pi / 2):
        raise ValueError("theta must be inside (-90°, 90°) of boresight")
    scale = {"published": 1.0, "textbook": 2.0 * math.pi}.get(form)
    if scale is None:
        raise ValueError(f"unknown form {form!r}: use published or textbook")
    sigma = 1.0 / (
        scale * (baseline_m / wavelength_m) * np.cos(theta) * np.sqrt(db_to_linear(snr_db))
    )
    out = np.rad2deg(sigma)
    return float(out) if np.ndim(out) == 0 else out


def sigma_monopulse_deg(snr_db: Any, *, beamwidth_deg: float = 45.0, k_m: float = 1.386) -> Any:
    """One-sigma angle error of amplitude monopulse, degrees (same unit as the beamwidth)."""
    out = beamwidth_deg / (k_m * np.sqrt(db_to_linear(snr_db)))
    return float(out) if np.ndim(out) == 0 else out
