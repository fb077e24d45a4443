"""Vectorised decoding of single-measurement frames: many frames, a few numpy passes.

A MEASUREMENT frame is 35 bytes before COBS and always 36 after (one code
byte per 254). Every 36-byte segment of a buffer is therefore a candidate:
the COBS code chains of all candidates are walked together (one numpy step
per code byte), the headers are checked column-wise and the CRC runs
byte-column by byte-column over all rows at once with a 256-entry table.
Rows that fail any check go back to the exact per-frame path, which
classifies the error and tries resynchronisation; so the result is the
same as decoding each frame on its own, only faster.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from rfsas_hw.board.framing import CRC_SIZE, HEADER_SIZE, MAGIC, crc_start
from rfsas_hw.board.messages import MEASUREMENT, Measurement

BODY = HEADER_SIZE + MEASUREMENT.size + CRC_SIZE
"""Bytes of a single-measurement frame before COBS (35)."""
WIRE = BODY + 1
"""Its COBS length without the delimiter (36)."""


def _crc_table() -> npt.NDArray[np.uint16]:
    table = np.zeros(256, dtype=np.uint16)
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        table[byte] = crc & 0xFFFF
    return table


CRC_TABLE = _crc_table()
_START = crc_start(Measurement.CRC_EXTRA)
_HEADER_FIXED = np.array([MAGIC, 0], dtype=np.uint8)  # magic, incompatible flags


def decode_measurement_rows(
    rows: npt.NDArray[np.uint8],
) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.uint8]]:
    """COBS-decode and check ``rows`` (k × 36 segment bytes) as MEASUREMENT frames.

    Returns ``(ok, frames)``: a mask of rows that are valid frames with no
    unknown incompatible flag, and the decoded bytes (k × 35).
    """
    k = rows.shape[0]
    out = rows.copy()
    idx = np.arange(k)
    pos = np.zeros(k, dtype=np.int64)
    ok = np.ones(k, dtype=bool)
    active = idx
    # walk every row's chain of code bytes at once; a code points at the next
    while active.size:
        nxt = pos[active] + rows[active, pos[active]]
        inside = nxt < WIRE
        ok[active[nxt > WIRE]] = False  # runs past the end: not COBS
        a = active[inside]
        out[a, nxt[inside]] = 0
        pos[a] = nxt[inside]
        active = a
    frames = out[:, 1:]
    ok &= (frames[:, 0] == MAGIC) & (frames[:, 1] == 0)
    ok &= (frames[:, 5] == Measurement.TYPE) & (frames[:, 6] == MEASUREMENT.size)
    ok &= frames[:, 7] == 0
    crc = np.full(k, _START, dtype=np.uint16)
    table = CRC_TABLE
    for j in range(BODY):
        crc = (crc << np.uint16(8)) ^ table[(crc >> np.uint16(8)) ^ frames[:, j]]
    ok &= crc == 0
    return ok, frames


def segments(arr: npt.NDArray[np.uint8]) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """Start and end offsets of the complete segments (before each 0x00) of a buffer."""
    ends = np.flatnonzero(arr == 0)
    starts = np.empty_like(ends)
    if ends.size:
        starts[0] = 0
        starts[1:] = ends[:-1] + 1
    return starts, ends
