"""The monopulse ratio and its sensitivity to each RSSI (method.md §4).

Two modes, named in every calibration file:

- ``db``: the published ratio on the readings as reported,
  ``ψ = (RSSI₁ − K_D·RSSI₂) / (RSSI₁ + K_D·RSSI₂)`` with RSSI in dBm.
  It depends on the absolute level: the same angle gives a smaller |ψ| for
  a weaker frame, so a table fitted at one level biases bearings at another.
- ``linear``: the same ratio on linear power (mW),
  ``ψ = (P₁ − K_D·P₂) / (P₁ + K_D·P₂) = tanh(ln10/20 · (ΔdB − 10·log10 K_D))``.
  It depends only on the difference of the readings, so it is independent of
  range and transmit power. It is the default.
"""

from __future__ import annotations

import math
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

Mode = Literal["db", "linear"]
MODES: tuple[Mode, ...] = ("db", "linear")
Array = npt.NDArray[np.floating[Any]]
_LN10_10 = math.log(10.0) / 10.0


def ratio(rssi1_dbm: Array, rssi2_dbm: Array, k_d: float, mode: Mode) -> Array:
    """Monopulse ratio ψ of RSSI pairs (dBm arrays, same shape).

    Raises:
        ValueError: unknown mode.
    """
    r1 = np.asarray(rssi1_dbm)
    r2 = np.asarray(rssi2_dbm)
    if r1.dtype != np.float32 or r2.dtype != np.float32:
        r1, r2 = r1.astype(np.float64, copy=False), r2.astype(np.float64, copy=False)
    dtype = r1.dtype.type
    if mode == "db":
        k = dtype(k_d)
        return (r1 - k * r2) / (r1 + k * r2)
    if mode == "linear":
        # tanh form of (P1 − K·P2)/(P1 + K·P2): no overflow, no 10** per sample
        scale, shift = dtype(0.5 * _LN10_10), dtype(0.5 * math.log(k_d))
        return np.tanh((r1 - r2) * scale - shift)
    raise ValueError(f"unknown monopulse mode {mode!r}: use db or linear")


def ratio_gradient(
    rssi1_dbm: Array, rssi2_dbm: Array, k_d: float, mode: Mode
) -> tuple[Array, Array]:
    """Partial derivatives ∂ψ/∂RSSI₁ and ∂ψ/∂RSSI₂, per dB.

    Raises:
        ValueError: unknown mode.
    """
    r1 = np.asarray(rssi1_dbm, dtype=np.float64)
    r2 = np.asarray(rssi2_dbm, dtype=np.float64)
    if mode == "db":
        s2 = (r1 + k_d * r2) ** 2
        return 2.0 * k_d * r2 / s2, -2.0 * k_d * r1 / s2
    if mode == "linear":
        psi = ratio(r1, r2, k_d, mode)
        d = 0.5 * _LN10_10 * (1.0 - psi**2)
        return d, -d
    raise ValueError(f"unknown monopulse mode {mode!r}: use db or linear")


def balance_k_d(rssi1_at_boresight_dbm: float, rssi2_at_boresight_dbm: float, mode: Mode) -> float:
    """K_D that makes ψ(0) = 0 for the mean readings at boresight.

    Raises:
        ValueError: unknown mode, or (db mode) a reading of 0 dBm or a sign change.
    """
    r1, r2 = float(rssi1_at_boresight_dbm), float(rssi2_at_boresight_dbm)
    if mode == "db":
        if r2 == 0.0 or r1 / r2 <= 0.0:
            raise ValueError("db-mode balance needs two readings of the same sign, not 0 dBm")
        return r1 / r2
    if mode == "linear":
        return float(10.0 ** ((r1 - r2) / 10.0))
    raise ValueError(f"unknown monopulse mode {mode!r}: use db or linear")
