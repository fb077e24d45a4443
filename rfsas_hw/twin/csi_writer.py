"""CSI from the twin: per-antenna channels from the geometry, written as FeitCSI files.

A two-antenna array on a baseline ``D`` (antenna 1 on the clockwise side of
antenna 0) hears each frame of :class:`~rfsas_hw.twin.world.Receptions` from
its true angle θ. On subcarrier k (frequency ``f_k = f_c + k·312.5 kHz``)::

    h_i,k = A_i · exp(j·(ψ + s·k + 2π·x_i·sin θ·f_k/c + φ_i + 2π·k·Δf·τ_i)) + n_i,k

with ``x_0 = 0, x_1 = D``; ``A_i = √SNR_i`` from the frame's true per-chain
SNR (the beams' gains included), ``n`` complex Gaussian of unit power (so the
per-subcarrier SNR equals the chain's), a random common phase ψ and
sampling-time slope ``s`` per frame, and the hardware's offset φ_1 and extra
chain delay τ_1 on antenna 1 (what a phase calibration must find). The
values are scaled per frame to 16-bit I/Q (as the card's AGC would) and
written in the FeitCSI layout that :mod:`rfsas_hw.sources.csi_feit` reads,
with the reported per-chain RSSI and the transmitter MAC. Seeded: the same
inputs give the same bytes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import SimulationError
from rfsas_hw.twin.world import Receptions

C_MPS = 299_792_458.0
SPACING_HZ = 312_500.0
FEIT_HEADER_BYTES = 272
FTM_CLOCK_NS = 3.125
FULL_SCALE = 8000.0
"""Largest |I|, |Q| a frame is scaled to (int16 leaves headroom for the noise)."""
_FEIT_HEADER = np.dtype(
    {
        "names": ["length", "ticks", "nrx", "ntx", "nsc", "energy", "mac"],
        "formats": ["<u4", "<u4", "u1", "u1", "<u4", ("<u4", 2), ("u1", 6)],
        "offsets": [0, 8, 46, 47, 52, 60, 68],
        "itemsize": FEIT_HEADER_BYTES,
    }
)
"""The fields of a FeitCSI frame header this writer fills (the rest stay zero)."""
_MAC_SHIFTS = np.arange(40, -1, -8, dtype=np.uint64)
"""Shifts of a 48-bit MAC's bytes, most significant first (the header is big-endian)."""


@dataclass(frozen=True, slots=True)
class CsiArray:
    """The twin's two-antenna CSI receiver."""

    baseline_m: float
    """Antenna spacing D, metres."""
    n_subcarriers: int = 56
    """Subcarriers reported (56: 20 MHz HT, indices ±1…±28)."""
    phase_offset_deg: float = 0.0
    """Hardware phase of antenna 1's chain relative to antenna 0's, degrees."""
    delay_ns: float = 0.0
    """Extra delay of antenna 1's chain, ns."""
    sto_max: float = 0.2
    """Largest per-frame sampling-time phase slope, rad per subcarrier."""

    def subcarriers(self) -> npt.NDArray[np.int16]:
        """Indices of the reported subcarriers (DC excluded)."""
        half = self.n_subcarriers // 2
        return np.concatenate(
            [np.arange(-half, 0), np.arange(1, self.n_subcarriers - half + 1)]
        ).astype(np.int16)


def synth_csi(
    array: CsiArray,
    true_deg: npt.ArrayLike,
    freq_mhz: npt.ArrayLike,
    snr_db: npt.ArrayLike,
    seed: int,
) -> npt.NDArray[np.complex128]:
    """Channels of every frame, shape (n, 2, 1, n_subcarriers), noise unit power.

    Args:
        array: the receiver.
        true_deg: angle from boresight per frame, degrees clockwise.
        freq_mhz: centre frequency per frame, MHz.
        snr_db: true SNR per frame and antenna, shape (n, 2), dB.
        seed: random seed.

    Raises:
        SimulationError: shapes disagree or a frequency is not positive.
    """
    theta = np.radians(np.asarray(true_deg, np.float64))
    n = len(theta)
    freq = np.broadcast_to(np.asarray(freq_mhz, np.float64), (n,)) * 1e6
    snr = np.asarray(snr_db, np.float64)
    if snr.shape != (n, 2):
        raise SimulationError(f"snr_db has shape {snr.shape}, expected ({n}, 2)")
    if n and not np.all(freq > 0):
        raise SimulationError("every frame needs a positive centre frequency")
    rng = np.random.default_rng(seed)
    k = array.subcarriers().astype(np.float64)
    f_k = freq[:, None] + k[None, :] * SPACING_HZ
    psi = rng.uniform(-math.pi, math.pi, n)
    slope = rng.uniform(-array.sto_max, array.sto_max, n)
    common = psi[:, None] + slope[:, None] * k[None, :]
    geo = 2 * math.pi * array.baseline_m * np.sin(theta)[:, None] * f_k / C_MPS
    hw = math.radians(array.phase_offset_deg) + 2 * math.pi * k * SPACING_HZ * array.delay_ns * 1e-9
    amp = np.sqrt(np.power(10.0, snr / 10.0))
    h = np.empty((n, 2, 1, len(k)), np.complex128)
    h[:, 0, 0] = amp[:, [0]] * np.exp(1j * common)
    h[:, 1, 0] = amp[:, [1]] * np.exp(1j * (common + geo + hw[None, :]))
    noise = rng.standard_normal((2, n, 2, 1, len(k))) * math.sqrt(0.5)
    h += noise[0] + 1j * noise[1]
    return h


def write_feitcsi(
    path: str | Path,
    t_ns: npt.ArrayLike,
    mac: npt.ArrayLike,
    rssi_dbm: npt.ArrayLike,
    h: npt.NDArray[np.complex128],
) -> int:
    """Write frames in the FeitCSI layout; returns the number of frames.

    Each frame is scaled so that its largest component is :data:`FULL_SCALE`
    (a common factor for both antennas keeps their phase and amplitude ratio).
    RSSI is written as the card does: energy = −dBm, 0 for a missing chain.

    Raises:
        SimulationError: shapes disagree.
    """
    t = np.asarray(t_ns, np.int64)
    macs = np.asarray(mac, np.uint64)
    rssi = np.asarray(rssi_dbm, np.float64)
    n, nrx, ntx, nsc = h.shape
    if len(t) != n or len(macs) != n or rssi.shape != (n, nrx):
        raise SimulationError("t_ns, mac, rssi_dbm and h disagree in frame count or antennas")
    peak = np.max(np.maximum(np.abs(h.real), np.abs(h.imag)), axis=(1, 2, 3))
    scale = FULL_SCALE / np.where(peak > 0, peak, 1.0)
    iq = np.empty((n, nrx, ntx, nsc, 2), "<i2")
    iq[..., 0] = np.round(h.real * scale[:, None, None, None])
    iq[..., 1] = np.round(h.imag * scale[:, None, None, None])
    ticks = (np.round(t / FTM_CLOCK_NS).astype(np.int64) & 0xFFFFFFFF).astype(np.uint32)
    head = np.zeros(n, _FEIT_HEADER)
    length = 4 * nrx * ntx * nsc  # bytes of I/Q after the header
    head["length"] = length
    head["ticks"] = ticks
    head["nrx"], head["ntx"], head["nsc"] = nrx, ntx, nsc
    chains = rssi[:, : min(nrx, 2)]
    finite = np.isfinite(chains)
    energy = np.clip(-np.round(np.where(finite, chains, -1.0)), 1, 255)
    head["energy"][:, : chains.shape[1]] = np.where(finite, energy, 0)
    head["mac"] = (macs[:, None] >> _MAC_SHIFTS) & np.uint64(0xFF)
    frames = np.empty((n, FEIT_HEADER_BYTES + length), np.uint8)
    frames[:, :FEIT_HEADER_BYTES] = head.view(np.uint8).reshape(n, FEIT_HEADER_BYTES)
    frames[:, FEIT_HEADER_BYTES:] = iq.reshape(n, length // 2).view(np.uint8)
    with open(path, "wb") as out:
        out.write(frames.tobytes())
    return int(n)


def write_sensor_csi(
    rec: Receptions, array: CsiArray, path: str | Path, seed: int
) -> npt.NDArray[np.intp]:
    """Write the frames a sensor heard as a FeitCSI capture; returns their rows in ``rec``.

    The channel of each frame comes from its true angle and true per-chain SNR
    (:func:`synth_csi`); the RSSI written is what the sensor's driver read
    (quantised, with its noise), so the amplitude monopulse sees the same
    readings as from a radiotap capture.

    Raises:
        SimulationError: the receptions lack two chains.
    """
    if rec.snr_db.ndim != 2 or rec.snr_db.shape[1] != 2:
        raise SimulationError("CSI needs a two-chain receiver")
    rows = np.flatnonzero(rec.heard.any(axis=1))
    h = synth_csi(array, rec.true_relative_deg[rows], rec.freq_mhz[rows], rec.snr_db[rows], seed)
    write_feitcsi(path, rec.t_ns[rows], rec.mac[rows], rec.chain_dbm[rows], h)
    return rows
