"""Measurement frames → columnar records → :class:`~rfsas_hw.records.ObservationBatch`.

The hot path of the serial driver: the payloads of MEASUREMENT and
MEASUREMENT_BATCH frames are joined and viewed as a numpy structured array,
so a chunk of frames becomes columns without a Python object per measurement.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import numpy.typing as npt

from rfsas_hw.board.framing import Frame
from rfsas_hw.board.messages import (
    FRAME_SEQ_NONE,
    MEASUREMENT,
    RSSI_NONE,
    Measurement,
    MeasurementBatch,
    PayloadError,
    batch_header,
)
from rfsas_hw.records import NO_SEQ, ObservationBatch, ObsFlag

RECORD = np.dtype(
    {
        "names": ["t_us", "mac", "freq_mhz", "channel", "kind", "flags", "frame_seq", "rssi"],
        "formats": ["<u8", ("u1", 6), "<u2", "u1", "u1", "u1", "<u2", ("i1", 4)],
        "offsets": [0, 8, 14, 16, 17, 18, 19, 21],
        "itemsize": MEASUREMENT.size,
    }
)
"""One version-1 measurement record (25 bytes, little-endian)."""

_MAC_SHIFTS = np.array([40, 32, 24, 16, 8, 0], dtype=np.uint64)
_TYPES = (Measurement.TYPE, MeasurementBatch.TYPE)


def is_measurement(frame: Frame) -> bool:
    """True for MEASUREMENT and MEASUREMENT_BATCH frames."""
    return frame.msg_type in _TYPES


def records(frames: Iterable[Frame]) -> npt.NDArray[np.void]:
    """The measurement records of ``frames`` (others are ignored), in order.

    Raises:
        PayloadError: a measurement payload is too short for its layout.
    """
    parts: list[bytes] = []
    size = MEASUREMENT.size
    for f in frames:
        p = f.payload
        if f.msg_type == Measurement.TYPE:
            if len(p) < size:
                raise PayloadError(f"MEASUREMENT seq {f.seq}: {len(p)} bytes < {size}")
            parts.append(p[:size] if len(p) > size else p)
        elif f.msg_type == MeasurementBatch.TYPE:
            count, rec = batch_header(p)
            if rec == size:
                parts.append(p[2 : 2 + count * size])
            else:
                parts.extend(p[2 + i * rec : 2 + i * rec + size] for i in range(count))
    return np.frombuffer(b"".join(parts), dtype=RECORD)


def to_observations(
    rec: npt.NDArray[np.void], t_ns: npt.NDArray[np.int64], n_antennas: int = 2
) -> ObservationBatch:
    """Columns of an :class:`ObservationBatch` from records and their host times (UTC ns)."""
    n = len(rec)
    mac = (rec["mac"].astype(np.uint64) << _MAC_SHIFTS).sum(axis=1, dtype=np.uint64)
    raw = rec["rssi"][:, :n_antennas]
    missing = raw == RSSI_NONE
    rssi = raw.astype(np.float32)
    rssi[missing] = np.nan
    flags = (rec["flags"] & (ObsFlag.RETRY | ObsFlag.BAD_FCS)).astype(np.uint16)
    flags[missing.any(axis=1)] |= np.uint16(ObsFlag.MISSING_CHAIN)
    fseq = rec["frame_seq"].astype(np.int32)
    fseq[fseq == FRAME_SEQ_NONE] = NO_SEQ
    return ObservationBatch(
        t_ns=np.asarray(t_ns, np.int64),
        mac=mac if n else np.empty(0, np.uint64),
        freq_mhz=rec["freq_mhz"].astype(np.int32),
        channel=rec["channel"].astype(np.int16),
        rssi_dbm=rssi.reshape(n, n_antennas),
        seq=fseq,
        kind=rec["kind"].astype(np.uint8),
        flags=flags,
    )
