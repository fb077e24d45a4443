"""Synthetic RSSI pairs from the antenna model: turntable logs, emulators, tests.

Everything here is seeded and vectorised. A reading is the received power
at the beam peak plus each antenna's pattern offset, plus Gaussian noise
(:func:`~rfsas_hw.rf.noise.rssi_sigma_db`), rounded to the card's step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rfsas_hw.rf.antenna import GaussianBeamPair
from rfsas_hw.rf.noise import quantise_db, rssi_sigma_db


@dataclass(frozen=True, slots=True)
class ReceiverModel:
    """How a two-chain receiver measures a frame."""

    noise_floor_dbm: float = -90.89
    """Power that SNR is measured against, dBm."""
    measurement_floor_db: float = 1.0
    """Per-chain RSSI spread at high SNR, dB (before quantisation)."""
    step_db: float = 1.0
    """Reporting step, dB (0 for unquantised)."""
    chain_offsets_db: tuple[float, float] = (0.0, 0.0)
    """Fixed gain imbalance of each chain, dB (what K_D calibrates away)."""


def rssi_pairs(
    theta_deg: npt.ArrayLike,
    peak_rx_dbm: npt.ArrayLike,
    antenna: GaussianBeamPair,
    receiver: ReceiverModel,
    rng: np.random.Generator,
) -> npt.NDArray[np.float64]:
    """Measured RSSI per antenna, dBm, shape ``(n, 2)``.

    ``theta_deg`` is array-relative (clockwise from boresight);
    ``peak_rx_dbm`` is the power an antenna would receive at its beam peak.
    """
    theta = np.atleast_1d(np.asarray(theta_deg, dtype=np.float64))
    peak = np.broadcast_to(np.asarray(peak_rx_dbm, dtype=np.float64), theta.shape)
    clean = peak[:, None] + antenna.gains_db(theta) - antenna.peak_gain_dbi
    clean = clean + np.asarray(receiver.chain_offsets_db)
    sigma = rssi_sigma_db(clean - receiver.noise_floor_dbm, receiver.measurement_floor_db)
    noisy = clean + sigma * rng.standard_normal(clean.shape)
    return quantise_db(noisy, receiver.step_db)


@dataclass(frozen=True, slots=True)
class TurntableSamples:
    """A turntable log: the angle of each reading and both RSSIs."""

    angle_deg: npt.NDArray[np.float64]
    """Turntable angle, degrees clockwise from boresight."""
    rssi1_dbm: npt.NDArray[np.float64]
    """Antenna 0 (squinted clockwise), dBm."""
    rssi2_dbm: npt.NDArray[np.float64]
    """Antenna 1 (squinted counter-clockwise), dBm."""
    channel: npt.NDArray[np.int16]
    """IEEE channel (0 when not recorded)."""


def turntable_sweep(
    angles_deg: npt.ArrayLike,
    repeats: int,
    peak_rx_dbm: float,
    antenna: GaussianBeamPair,
    receiver: ReceiverModel,
    seed: int,
    channel: int = 0,
) -> TurntableSamples:
    """Simulate a turntable run: ``repeats`` frames at each angle, in angle order."""
    angles = np.repeat(np.asarray(angles_deg, dtype=np.float64), repeats)
    rng = np.random.default_rng(seed)
    r = rssi_pairs(angles, peak_rx_dbm, antenna, receiver, rng)
    return TurntableSamples(angles, r[:, 0], r[:, 1], np.full(len(angles), channel, np.int16))
