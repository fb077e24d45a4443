"""Intel 5300 CSI Tool ``.dat`` files, read here (no dependency).

The file is a sequence of records ``[u16 big-endian length][u8 code][length−1
bytes]``. Code ``0xBB`` is a beamforming-feedback record (little-endian)::

    0  u32 timestamp_low   µs clock of the card, wraps every 2³² µs
    4  u16 bfee_count
    8  u8  Nrx, u8 Ntx
    10 u8  rssi_a, rssi_b, rssi_c   dB relative to the AGC; 0 = no reading
    13 i8  noise (−127: not reported)
    14 u8  agc
    15 u8  antenna_sel   2 bits per RF chain: which antenna feeds it
    16 u16 len           bytes of the packed CSI that follow
    18 u16 fake_rate_n_flags (bit 11: 40 MHz)
    20 ... 30 subcarriers × (3 skipped bits + Nrx·Ntx × (8-bit I, 8-bit Q))

Other codes are skipped. The CSI rows come per RF chain; the permutation in
``antenna_sel`` maps chain k to antenna ``perm[k]`` and is undone here, so
antenna 0 is port A. RSSI is per antenna port already. The per-chain RSSI in
dBm is ``rssi_x − 44 − agc`` (the tool's own conversion). The 0xBB records
carry no MAC address: a capture with ``connector_log`` 0x1 has MAC 0; with
0x5 the k-th 0xC1 record (the 802.11 frame) gives the k-th frame its
transmitter address and sequence number.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import CaptureFormatError
from rfsas_hw.records import ObsFlag
from rfsas_hw.sources.csi_frames import (
    CsiCapture,
    CsiFrames,
    intel_grouped_subcarriers,
    new_frames,
)

BFEE_CODE = 0xBB
FRAME_CODE = 0xC1
"""A record holding the 802.11 frame (``connector_log`` 0x4): fc, duration, addr1,
addr2 (the transmitter), addr3, sequence control, … — the k-th pairs with the
k-th 0xBB record."""
HEADER_BYTES = 20
N_SUBCARRIERS = 30
RSSI_OFFSET_DB = 44.0
"""The 5300 tool's offset from its RSSI scale (plus AGC) to dBm."""
TIMER_WRAP_US = 1 << 32
_HEADER = np.dtype(
    [
        ("timestamp_low", "<u4"),
        ("bfee_count", "<u2"),
        ("reserved", "<u2"),
        ("nrx", "u1"),
        ("ntx", "u1"),
        ("rssi", "u1", (3,)),
        ("noise", "i1"),
        ("agc", "u1"),
        ("antenna_sel", "u1"),
        ("len", "<u2"),
        ("rate", "<u2"),
    ]
)


def _packed_len(nrx: int, ntx: int) -> int:
    return (N_SUBCARRIERS * (nrx * ntx * 16 + 3) + 7) // 8


def _unpack(payload: npt.NDArray[np.uint8], nrx: int, ntx: int) -> npt.NDArray[np.complex64]:
    """Packed CSI of frames with one (Nrx, Ntx) → complex array (n, chain, stream, subcarrier)."""
    m = nrx * ntx
    sc = np.arange(N_SUBCARRIERS)[:, None]
    j = np.arange(m)[None, :]
    bit = sc * (3 + 16 * m) + 3 + 16 * j
    byte, rem = bit // 8, (bit % 8).astype(np.uint16)
    p = payload.astype(np.uint16)
    pad = np.zeros((p.shape[0], 3), np.uint16)
    p = np.concatenate([p, pad], axis=1)

    def value(offset: int) -> npt.NDArray[np.int8]:
        raw = (p[:, byte + offset] >> rem) | (p[:, byte + offset + 1] << (8 - rem))
        out: npt.NDArray[np.int8] = (raw & 0xFF).astype(np.uint8).view(np.int8)
        return out

    re = value(0).astype(np.float32)
    im = value(1).astype(np.float32)
    # j = tx + Ntx·rx (the tool writes streams fastest)
    h = (re + 1j * im).reshape(-1, N_SUBCARRIERS, nrx, ntx)
    return np.ascontiguousarray(h.transpose(0, 2, 3, 1)).astype(np.complex64)


def read_intel5300(path: str | Path, freq_mhz: int = 0) -> CsiCapture:
    """Every beamforming record of a 5300 ``.dat`` file, in runs of one bandwidth.

    ``freq_mhz`` is the channel the capture was made on (the file does not
    say); at 2.4 GHz every frame is flagged ``PHASE_AMBIGUOUS`` (the card's
    per-chain phase may be off by a multiple of π/2 there).

    Raises:
        CaptureFormatError: the file holds no 0xBB record, a record's length
            disagrees with its antenna counts, or the file ends inside a record
            (file, record number and byte offset named).
    """
    name = str(path)
    data = np.fromfile(path, dtype=np.uint8)
    offsets: list[int] = []
    frame_offsets: list[int] = []
    pos, record, total = 0, 0, len(data)
    problems: list[tuple[str, CaptureFormatError]] = []
    while pos + 3 <= total:
        length = (int(data[pos]) << 8) | int(data[pos + 1])
        code = int(data[pos + 2])
        if length < 1 or pos + 2 + length > total:
            problems.append(
                (
                    "truncated record",
                    CaptureFormatError(
                        f"{name}: record {record} at byte {pos}: length {length} runs past "
                        f"the end of the file ({total} bytes)"
                    ),
                )
            )
            break
        if code == BFEE_CODE:
            offsets.append(pos + 3)
        elif code == FRAME_CODE and length - 1 >= 24:
            frame_offsets.append(pos + 3)
        pos += 2 + length
        record += 1
    if not offsets:
        raise CaptureFormatError(
            f"{name}: no Intel 5300 beamforming record (code 0xBB) in {total} bytes"
            + (f"; {problems[0][1]}" if problems else "")
        )
    starts = np.asarray(offsets)
    heads = np.frombuffer(
        np.stack([data[s : s + HEADER_BYTES] for s in starts]).tobytes(), dtype=_HEADER
    )
    nrx = heads["nrx"].astype(int)
    ntx = heads["ntx"].astype(int)
    good = (nrx >= 1) & (nrx <= 3) & (ntx >= 1) & (ntx <= 3)
    expect = np.where(good, (N_SUBCARRIERS * (nrx * ntx * 16 + 3) + 7) // 8, -1)
    good &= heads["len"].astype(int) == expect
    notes: Counter[str] = Counter()
    if frame_offsets and len(frame_offsets) != len(offsets):
        # pairing by order is then unsure past the first mismatch: say so
        notes["0xC1 frame records not one per 0xBB record"] = len(frame_offsets)
    for k in np.flatnonzero(~good):
        problems.append(
            (
                "bad record",
                CaptureFormatError(
                    f"{name}: 0xBB record at byte {int(starts[k]) - 3}: Nrx={nrx[k]} "
                    f"Ntx={ntx[k]} len={int(heads['len'][k])} does not match its antenna counts"
                ),
            )
        )
    keep = np.flatnonzero(good)
    if len(keep) == 0:
        raise problems[-1][1]
    max_rx, max_tx = int(nrx[keep].max()), int(ntx[keep].max())
    sel_all = heads["antenna_sel"].astype(int)
    perm_all = np.stack([(sel_all >> (2 * k)) & 0x3 for k in range(3)], axis=1)
    wide = (heads["rate"].astype(int) & 0x800) != 0
    out: list[CsiFrames] = []
    # runs of one bandwidth keep file order
    bounds = np.flatnonzero(np.diff(wide[keep].astype(int))) + 1
    for run in np.split(keep, bounds):
        bw = 40 if wide[run[0]] else 20
        frames = new_frames("intel5300", len(run), max_rx, max_tx, intel_grouped_subcarriers(bw))
        h = heads[run]
        t_us = h["timestamp_low"].astype(np.int64)
        frames.t_ns = t_us * 1000  # unwrapped below over the whole file
        rssi = h["rssi"].astype(np.float32) - RSSI_OFFSET_DB - h["agc"].astype(np.float32)[:, None]
        sentinel = h["rssi"] == 0
        rssi[sentinel] = np.nan
        frames.rssi_dbm[:, :] = rssi[:, :max_rx]
        frames.flags[np.any(sentinel[:, :max_rx], axis=1)] |= np.uint16(ObsFlag.SENTINEL_CHAIN)
        frames.freq_mhz[:] = freq_mhz
        for row, i in enumerate(run):
            if i < len(frame_offsets):
                f = frame_offsets[i]
                frames.mac[row] = int.from_bytes(data[f + 10 : f + 16].tobytes(), "big")
                frames.seq[row] = int.from_bytes(data[f + 22 : f + 24].tobytes(), "little") >> 4
        sel = h["antenna_sel"].astype(int)
        perm = np.stack([(sel >> (2 * k)) & 0x3 for k in range(3)], axis=1)
        for rx_n, tx_n in sorted({(int(nrx[i]), int(ntx[i])) for i in run}):
            idx = np.flatnonzero((nrx[run] == rx_n) & (ntx[run] == tx_n))
            length = _packed_len(rx_n, tx_n)
            payload = np.stack(
                [
                    data[starts[run[i]] + HEADER_BYTES : starts[run[i]] + HEADER_BYTES + length]
                    for i in idx
                ]
            )
            chains = _unpack(payload, rx_n, tx_n)
            p = perm[idx, :rx_n]
            valid = np.all(np.sort(p, axis=1) == np.arange(rx_n)[None, :], axis=1)
            # chain k carries antenna perm[k]; an invalid perm keeps chain order
            dest = np.where(valid[:, None], p, np.arange(rx_n)[None, :])
            rows = np.repeat(idx, rx_n)
            frames.h[rows, dest.ravel(), :tx_n, :] = chains.reshape(-1, tx_n, N_SUBCARRIERS)
            if (~valid).any():
                frames.flags[idx[~valid]] |= np.uint16(ObsFlag.MISSING_CHAIN)
                notes["invalid antenna permutation"] += int((~valid).sum())
        if 2400 <= freq_mhz < 2500:
            frames.flags |= np.uint16(ObsFlag.PHASE_AMBIGUOUS)
        out.append(frames)
    _unwrap_times(out)
    used = np.unique(perm_all[keep][:, : int(nrx[keep].max())], axis=0)
    notes["antenna permutations"] = len(used)
    return CsiCapture(name, "intel5300", out, "dBm", problems, notes)


def _unwrap_times(blocks: list[CsiFrames]) -> None:
    """Undo the 32-bit µs wrap across the whole file (times stay in file order)."""
    t = np.concatenate([b.t_ns // 1000 for b in blocks])
    steps = np.diff(t)
    # a wrap is a fall by most of the 2³² µs range; small falls are records out of order
    wraps = np.concatenate([[0], np.cumsum(steps < -(TIMER_WRAP_US // 2))])
    t = t + wraps * TIMER_WRAP_US
    start = 0
    for b in blocks:
        b.t_ns = (t[start : start + len(b)] * 1000).astype(np.int64)
        start += len(b)
