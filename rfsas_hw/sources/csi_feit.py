"""FeitCSI (Intel AX200/AX210) ``.csi`` files, read here (no dependency).

Each frame is a 272-byte little-endian header followed by its CSI::

    0   u32 csi_length     bytes of CSI after the header
    8   u32 ftm_clock      card clock (320 MHz ticks, wraps every 13.4 s)
    46  u8  n_rx, 47 u8 n_tx
    52  u32 n_subcarriers
    60  u32 rssi_1, 64 u32 rssi_2   energy, dBm = −value (0 = no reading)
    68  6 bytes source MAC
    272 CSI: n_rx × n_tx × n_subcarriers of (i16 I, i16 Q)

The file does not record the channel frequency: pass it as ``freq_mhz``.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import CaptureFormatError
from rfsas_hw.records import ObsFlag
from rfsas_hw.sources.csi_frames import CsiCapture, CsiFrames, new_frames, ofdm_subcarriers

HEADER_BYTES = 272
FTM_CLOCK_NS = 3.125
"""Tick of the AX200's FTM clock (320 MHz), ns."""


_Head = tuple[int, int, int, int, int, int, int, int]
"""(csi length, n_rx, n_tx, n_subcarriers, clock, rssi_1, rssi_2, mac)."""


def _header(raw: bytes, pos: int, total: int) -> _Head | None:
    """The header at ``pos`` if its fields are consistent, else None."""
    length = int.from_bytes(raw[pos : pos + 4], "little")
    nrx, ntx = raw[pos + 46], raw[pos + 47]
    nsc = int.from_bytes(raw[pos + 52 : pos + 56], "little")
    sane = 1 <= nrx <= 4 and 1 <= ntx <= 4 and 1 <= nsc <= 4096
    if not sane or length != 4 * nrx * ntx * nsc or pos + HEADER_BYTES + length > total:
        return None
    return (
        length,
        nrx,
        ntx,
        nsc,
        int.from_bytes(raw[pos + 8 : pos + 12], "little"),
        int.from_bytes(raw[pos + 60 : pos + 64], "little"),
        int.from_bytes(raw[pos + 64 : pos + 68], "little"),
        int.from_bytes(raw[pos + 68 : pos + 74], "big"),
    )


def _resync(raw: bytes, start: int, total: int, layout: tuple[int, ...]) -> int | None:
    """The next position at or after ``start`` holding a header of ``layout``
    (n_rx, n_tx, n_subcarriers), or None."""
    length = (4 * layout[0] * layout[1] * layout[2]).to_bytes(4, "little")
    pos = raw.find(length, start)
    while pos != -1 and pos + HEADER_BYTES <= total:
        head = _header(raw, pos, total)
        if head is not None and head[1:4] == layout:
            return pos
        pos = raw.find(length, pos + 1)
    return None


def _bodies(raw: bytes, starts: npt.NDArray[np.int64], length: int) -> npt.NDArray[np.int16]:
    """The I/Q words after the headers at ``starts`` (frames of one layout), shape (n, length/2).

    Frames that follow each other without a gap are cut from one view of the file.
    """
    buf = np.frombuffer(raw, np.uint8)
    stride = HEADER_BYTES + length
    out = np.empty((len(starts), length // 2), "<i2")
    cuts = np.flatnonzero(np.diff(starts) != stride) + 1
    for rows in np.split(np.arange(len(starts)), cuts):
        first = int(starts[rows[0]])
        run = buf[first : first + stride * len(rows)].reshape(len(rows), stride)
        out[rows] = np.ascontiguousarray(run[:, HEADER_BYTES:]).view("<i2")
    return out


def read_feitcsi(path: str | Path, freq_mhz: int = 0) -> CsiCapture:
    """Every frame of a FeitCSI capture, in runs of one layout.

    Raises:
        CaptureFormatError: the first header is implausible (not a FeitCSI file);
            a later broken frame ends the read and is reported as a problem.
    """
    name = str(path)
    raw = Path(path).read_bytes()
    total = len(raw)
    pos = 0
    heads: list[tuple[int, int, int, int, int, int, int, int, int]] = []  # (pos, *_Head)
    problems: list[tuple[str, CaptureFormatError]] = []
    while pos < total:
        if pos + HEADER_BYTES > total:
            problems.append(
                (
                    "truncated frame",
                    CaptureFormatError(
                        f"{name}: frame {len(heads)} at byte {pos}: {total - pos} bytes left, "
                        f"a header needs {HEADER_BYTES}"
                    ),
                )
            )
            break
        head = _header(raw, pos, total)
        if head is None:
            err = CaptureFormatError(
                f"{name}: frame {len(heads)} at byte {pos}: not a FeitCSI frame header "
                "(antenna, subcarrier and length fields disagree or run past the end)"
            )
            if not heads:
                raise err
            # resynchronise on the next header of the layout seen so far
            found = _resync(raw, pos + 1, total, heads[-1][2:5])
            where = f"skipped to byte {found}" if found is not None else "rest of file lost"
            problems.append(("bad frame", CaptureFormatError(f"{err}; {where}")))
            if found is None:
                break
            pos = found
            continue
        heads.append((pos, *head))
        pos += HEADER_BYTES + head[0]
    notes: Counter[str] = Counter()
    blocks: list[CsiFrames] = []
    i = 0
    while i < len(heads):
        layout = heads[i][2:5]
        j = i
        while j < len(heads) and heads[j][2:5] == layout:
            j += 1
        nrx, ntx, nsc = layout
        n = j - i
        frames = new_frames("feitcsi", n, nrx, ntx, ofdm_subcarriers(nsc))
        cols = np.array([(hd[0], hd[5], hd[6], hd[7], hd[8]) for hd in heads[i:j]], np.int64)
        body = _bodies(raw, cols[:, 0], heads[i][1]).astype(np.float32)
        frames.h[:] = (body[:, 0::2] + 1j * body[:, 1::2]).reshape(n, nrx, ntx, nsc)
        frames.t_ns[:] = cols[:, 1]
        frames.mac[:] = cols[:, 4]
        energy = cols[:, 2 : 2 + min(nrx, 2)]
        read = energy != 0
        frames.rssi_dbm[:, : energy.shape[1]] = np.where(read, -energy, np.nan)
        frames.flags[~read.all(axis=1)] |= np.uint16(ObsFlag.SENTINEL_CHAIN)
        frames.freq_mhz[:] = freq_mhz
        blocks.append(frames)
        i = j
    ticks = np.concatenate([b.t_ns for b in blocks]) if blocks else np.zeros(0, np.int64)
    wraps = np.concatenate([[0], np.cumsum(np.diff(ticks) < -(1 << 31))]).astype(np.int64)
    ticks = ((ticks + (wraps << 32)) * FTM_CLOCK_NS).astype(np.int64)
    start = 0
    for b in blocks:
        b.t_ns = ticks[start : start + len(b)]
        start += len(b)
    return CsiCapture(name, "feitcsi", blocks, "dBm", problems, notes)
