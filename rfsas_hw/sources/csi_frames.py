"""Decoded CSI captures, whatever the tool: one uniform set of arrays per layout.

Each reader (:mod:`~rfsas_hw.sources.csi_intel`, :mod:`~rfsas_hw.sources.csi_feit`,
:mod:`~rfsas_hw.sources.csi_csiread`) turns a file into :class:`CsiFrames`
blocks, one per run of frames with the same antenna, stream and subcarrier
layout. This module holds that record, the subcarrier layouts, the flags for
the documented oddities and the inter-chain phase statistics that
``rfsas replay`` reports.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import CaptureFormatError
from rfsas_hw.records import NO_SEQ, CsiBlock, ObservationBatch, ObsFlag

SUBCARRIER_SPACING_HZ = 312_500.0
"""Spacing of 802.11n/ac subcarriers, Hz (index 1 is this far above the centre)."""
PHASE_JUMP_DEG = 60.0
"""An inter-chain phase step larger than this between consecutive frames of one
transmitter is flagged ``PHASE_JUMP``; the spreads measured on public samples
are 8–16° (Atheros, QCA9300), so 60° is well outside the noise."""


def intel_grouped_subcarriers(bandwidth_mhz: int) -> npt.NDArray[np.int16]:
    """The 30 subcarriers the Intel 5300 reports (grouping Ng = 2 at 20 MHz, 4 at 40 MHz)."""
    if bandwidth_mhz == 40:
        return np.arange(-58, 59, 4, dtype=np.int16)
    low = np.arange(-28, -1, 2)
    high = np.arange(1, 28, 2)
    return np.concatenate([low, [-1], high, [28]]).astype(np.int16)


def ofdm_subcarriers(count: int) -> npt.NDArray[np.int16]:
    """Subcarrier indices of a full CSI report of ``count`` tones (DC excluded).

    Known layouts: 52/56 (20 MHz HT), 114 (40 MHz), 242 (80 MHz VHT or 20 MHz HE),
    484 (HE 40), 996 (HE 80). Any other count is taken as contiguous tones
    around the centre without DC.
    """
    half_gap = {52: 0, 56: 0, 114: 1, 242: 1, 484: 2, 996: 2}.get(count)
    if half_gap is None:
        half_gap = 0
    side = count // 2
    low = np.arange(-side - half_gap, -half_gap, dtype=np.int32)
    high = np.arange(half_gap + 1, half_gap + 1 + count - side, dtype=np.int32)
    return np.concatenate([low, high]).astype(np.int16)


def channel_of(freq_mhz: int) -> int:
    """IEEE channel number of a centre frequency in MHz (0 if unknown)."""
    if freq_mhz == 2484:
        return 14
    if 2412 <= freq_mhz <= 2472:
        return (freq_mhz - 2407) // 5
    if 5000 <= freq_mhz <= 5900:
        return (freq_mhz - 5000) // 5
    if 5955 <= freq_mhz <= 7115:
        return (freq_mhz - 5950) // 5
    return 0


@dataclass(slots=True)
class CsiFrames:
    """Frames of one CSI capture that share one layout, as arrays (row = frame)."""

    fmt: str
    """Tool that wrote the file: ``intel5300``, ``atheros``, ``picoscenes``, ``feitcsi``,
    ``nexmon``."""
    t_ns: npt.NDArray[np.int64]
    """Frame time, ns: UTC where the tool records it, else since the tool's own clock origin."""
    mac: npt.NDArray[np.uint64]
    """Transmitter MAC (48-bit int, raw), 0 where the format carries none."""
    seq: npt.NDArray[np.int32]
    """802.11 sequence number, or ``NO_SEQ``."""
    freq_mhz: npt.NDArray[np.int32]
    """Centre frequency, MHz (0 if unknown)."""
    rssi_dbm: npt.NDArray[np.float32]
    """Signal per receive antenna (antenna order as wired), dBm where the tool reports
    dBm, else the tool's dB scale (see ``rssi_unit``); NaN where missing."""
    h: npt.NDArray[np.complex64]
    """Channel, shape (n, n_rx, n_tx, n_subcarriers); NaN where an antenna or stream is absent."""
    subcarrier: npt.NDArray[np.int16]
    """Subcarrier index per CSI column."""
    flags: npt.NDArray[np.uint16]
    """:class:`~rfsas_hw.records.ObsFlag` bits."""

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    @property
    def n_rx(self) -> int:
        """Receive antennas."""
        return int(self.h.shape[1])

    def to_batch(self) -> ObservationBatch:
        """The frames as observations with their CSI attached."""
        freq = self.freq_mhz
        channel = np.array([channel_of(int(f)) for f in freq], np.int16)
        return ObservationBatch(
            t_ns=self.t_ns,
            mac=self.mac,
            freq_mhz=freq,
            channel=channel,
            rssi_dbm=self.rssi_dbm,
            seq=self.seq,
            flags=self.flags,
            csi=CsiBlock(self.h, self.subcarrier),
        )


def new_frames(
    fmt: str,
    n: int,
    n_rx: int,
    n_tx: int,
    subcarrier: npt.NDArray[np.int16],
) -> CsiFrames:
    """Blank frames to fill: times 0, no MAC, no sequence, NaN RSSI and CSI."""
    return CsiFrames(
        fmt=fmt,
        t_ns=np.zeros(n, np.int64),
        mac=np.zeros(n, np.uint64),
        seq=np.full(n, NO_SEQ, np.int32),
        freq_mhz=np.zeros(n, np.int32),
        rssi_dbm=np.full((n, n_rx), np.nan, np.float32),
        h=np.full((n, n_rx, n_tx, len(subcarrier)), np.nan + 0j, np.complex64),
        subcarrier=np.asarray(subcarrier, np.int16),
        flags=np.zeros(n, np.uint16),
    )


@dataclass(slots=True)
class CsiCapture:
    """A whole CSI file: its frame blocks, the records lost and what was noticed."""

    path: str
    """File it was read from."""
    fmt: str
    """Tool format (see :attr:`CsiFrames.fmt`)."""
    blocks: list[CsiFrames]
    """Runs of frames with one layout, in file order."""
    rssi_unit: str = "dBm"
    """What the RSSI numbers are: ``dBm`` or the tool's own dB scale."""
    problems: list[tuple[str, CaptureFormatError]] = field(default_factory=list)
    """Records that could not be decoded: (reason, error naming file and offset)."""
    notes: Counter[str] = field(default_factory=Counter)
    """Oddities met while decoding, counted."""

    @property
    def frames(self) -> int:
        """Frames decoded."""
        return sum(len(b) for b in self.blocks)


def pair_products(h: npt.NDArray[np.complex64], a: int, b: int) -> npt.NDArray[np.complex128]:
    """Σ over subcarriers of ``h_a·conj(h_b)`` on the first stream, per frame (NaN-safe).

    Its angle is the inter-chain phase of the frame; a sampling-time offset,
    common to both chains, cancels in the product.
    """
    prod = h[:, a, 0, :].astype(np.complex128) * np.conj(h[:, b, 0, :].astype(np.complex128))
    prod = np.where(np.isfinite(prod), prod, 0.0)
    out: npt.NDArray[np.complex128] = prod.sum(axis=1)
    return out


def circular_std_deg(z: npt.NDArray[Any]) -> float:
    """Circular standard deviation of the angles of ``z`` (zeros ignored), degrees."""
    z = np.asarray(z)
    mag = np.abs(z)
    keep = mag > 0
    if not keep.any():
        return math.nan
    r = float(np.abs(np.mean(z[keep] / mag[keep])))
    return math.degrees(math.sqrt(-2.0 * math.log(min(max(r, 1e-300), 1.0))))


@dataclass(slots=True)
class PhaseStats:
    """Inter-chain phase of one antenna pair over a capture."""

    a: int
    """First antenna."""
    b: int
    """Second antenna."""
    frames: int
    """Frames where both antennas carried CSI."""
    mean_deg: float
    """Circular mean of the per-frame phase of ``h_a·conj(h_b)``, degrees."""
    std_deg: float
    """Circular standard deviation of it across frames, degrees."""


class PhaseAccumulator:
    """Running inter-chain phase statistics per antenna pair (unit phasors summed)."""

    def __init__(self) -> None:
        self._sum: dict[tuple[int, int], complex] = {}
        self._count: Counter[tuple[int, int]] = Counter()

    def add(self, h: npt.NDArray[np.complex64]) -> None:
        """Add the frames of one CSI array, shape (n, n_rx, n_tx, n_sc)."""
        for a in range(h.shape[1]):
            for b in range(a + 1, h.shape[1]):
                z = pair_products(h, a, b)
                mag = np.abs(z)
                keep = mag > 0
                if not keep.any():
                    continue
                self._sum[(a, b)] = self._sum.get((a, b), 0j) + complex(np.sum(z[keep] / mag[keep]))
                self._count[(a, b)] += int(keep.sum())

    def result(self) -> list[PhaseStats]:
        """Statistics of every pair seen, in pair order."""
        out = []
        for (a, b), total in sorted(self._sum.items()):
            n = self._count[(a, b)]
            r = abs(total) / n
            std = math.degrees(math.sqrt(-2.0 * math.log(min(max(r, 1e-300), 1.0))))
            out.append(PhaseStats(a, b, n, math.degrees(math.atan2(total.imag, total.real)), std))
        return out


def flag_phase_jumps(frames: CsiFrames, limit_deg: float = PHASE_JUMP_DEG) -> int:
    """Set ``PHASE_JUMP`` where a pair's phase moved more than ``limit_deg`` since the
    previous frame of the same transmitter; returns how many frames were flagged."""
    n = len(frames)
    if n < 2 or frames.n_rx < 2:
        return 0
    jump = np.zeros(n, bool)
    order = np.argsort(frames.mac, kind="stable")
    same = frames.mac[order][1:] == frames.mac[order][:-1]
    limit = math.radians(limit_deg)
    for b in range(1, frames.n_rx):
        z = pair_products(frames.h, 0, b)[order]
        ok = (np.abs(z[1:]) > 0) & (np.abs(z[:-1]) > 0) & same
        step = np.abs(np.angle(z[1:] * np.conj(z[:-1])))
        jump[order[1:][ok & (step > limit)]] = True
    frames.flags[jump] |= np.uint16(ObsFlag.PHASE_JUMP)
    return int(jump.sum())


def mark_missing(frames: CsiFrames) -> None:
    """Flag frames with a missing chain: NaN RSSI or an all-zero/NaN CSI row."""
    dead = ~np.any(np.isfinite(frames.h) & (frames.h != 0), axis=(2, 3))
    frames.h[dead] = np.nan
    frames.rssi_dbm[dead] = np.nan
    rssi_ok = np.isfinite(frames.rssi_dbm)
    # a format without any RSSI (old nexmon) is NO_SIGNAL, not a missing chain
    no_rssi = ~np.any(rssi_ok, axis=1)
    missing = np.any(dead, axis=1) | (np.any(~rssi_ok, axis=1) & ~no_rssi)
    frames.flags[missing] |= np.uint16(ObsFlag.MISSING_CHAIN)
    frames.flags[no_rssi] |= np.uint16(ObsFlag.NO_SIGNAL)
