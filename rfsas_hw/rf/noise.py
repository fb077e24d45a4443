"""How noisy an RSSI reading is, and what a card reports.

The spread of one RSSI reading, in dB, combines the card's measurement
floor (gain steps, AGC, estimator noise) and the thermal term of a power
estimate at finite SNR::

    σ_rssi² = floor_db² + (thermal_k_db / √SNR)²

``thermal_k_db = 10/ln 10 ≈ 4.343 dB``: the standard deviation of
``10·log10`` of a power reading whose relative error is ``1/√SNR`` (a power
estimate averaged over the preamble; one-sample estimates are √2 worse).
Cards report whole dB; rounding adds a uniform error of variance ``step²/12``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

THERMAL_K_DB = 10.0 / math.log(10.0)


def rssi_sigma_db(snr_db: Any, floor_db: float) -> npt.NDArray[np.float64]:
    """One-sigma spread of an RSSI reading before quantisation, dB."""
    snr = np.power(10.0, np.asarray(snr_db, dtype=np.float64) / 10.0)
    return np.sqrt(floor_db**2 + THERMAL_K_DB**2 / np.maximum(snr, 1e-12))


def quantise_db(rssi_dbm: Any, step_db: float = 1.0) -> npt.NDArray[np.float64]:
    """Round readings to the card's step (1 dB for monitor-mode Wi-Fi cards)."""
    if step_db <= 0:
        return np.asarray(rssi_dbm, dtype=np.float64)
    return np.floor(np.asarray(rssi_dbm, dtype=np.float64) / step_db + 0.5) * step_db


def quantisation_variance_db2(step_db: float = 1.0) -> float:
    """Variance added by rounding to ``step_db``, dB²."""
    return step_db**2 / 12.0
