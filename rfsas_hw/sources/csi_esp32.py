"""ESP32 CSI text (``CSI_DATA,…`` lines, with or without a header), read here.

Each line: ``CSI_DATA`` then 24 fields — role, MAC, RSSI (dBm), rate,
sig_mode, mcs, bandwidth, smoothing, not_sounding, aggregation, stbc,
fec_coding, sgi, noise_floor, ampdu_cnt, channel, secondary_channel,
local_timestamp (µs), ant, sig_len, rx_state, real_time_set, real_timestamp,
len — and the CSI as ``[v0 v1 …]``: ``len`` signed bytes, two per subcarrier
(imaginary first). The first 128 bytes are the legacy long training field, 64
subcarriers in FFT order (0…31, then −32…−1); only that part is kept, so every
frame has the same layout.

One antenna per packet: the frames carry RSSI and CSI but no phase
difference; the interferometer and the two-antenna monopulse have nothing to
work on (the pipeline counts them as ``missing_chain``).
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path

import numpy as np

from rfsas_hw.errors import CaptureFormatError, DataFormatError
from rfsas_hw.records import mac_to_int
from rfsas_hw.sources.csi_frames import CsiCapture, new_frames

FIELDS = 25
"""Comma-separated fields before the CSI array (``CSI_DATA`` included)."""
LLTF_BYTES = 128


def _subcarriers() -> np.ndarray:
    idx = np.arange(64)
    return np.where(idx < 32, idx, idx - 64).astype(np.int16)


def read_esp32(path: str | Path, freq_mhz: int = 0) -> CsiCapture:
    """Every ``CSI_DATA`` line of an ESP32 CSI text file; a bad line costs only itself.

    Raises:
        CaptureFormatError: the file holds no readable ``CSI_DATA`` line.
    """
    name = str(path)
    lines = Path(path).read_text(encoding="utf-8", errors="replace").splitlines()
    rows: list[tuple[int, float, int, int, np.ndarray]] = []
    problems: list[tuple[str, CaptureFormatError]] = []
    short = 0
    for line_no, line in enumerate(lines, start=1):
        if not line.startswith("CSI_DATA"):
            continue
        head, bracket, tail = line.partition("[")
        fields = head.rstrip(",").split(",")
        try:
            if not bracket or "]" not in tail or len(fields) < FIELDS:
                raise ValueError(f"{len(fields)} fields before the CSI, expected {FIELDS}")
            values = np.array(tail.partition("]")[0].split(), dtype=np.int64)
            declared = int(fields[24])
            if len(values) < LLTF_BYTES or len(values) > declared:
                raise ValueError(
                    f"{len(values)} CSI values (the line says {declared}; "
                    f"at least {LLTF_BYTES} needed)"
                )
            # loggers often print only the first part of the array: fine, it is all we use
            short += len(values) < declared
            if np.any(np.abs(values) > 128):
                raise ValueError("CSI values are not signed bytes")
            mac = mac_to_int(fields[2])
            rssi = float(fields[3])
            channel = int(fields[16])
            t_us = int(fields[18])
        except (ValueError, DataFormatError) as err:
            problems.append(("bad line", CaptureFormatError(f"{name}: line {line_no}: {err}")))
            continue
        rows.append((mac, rssi, channel, t_us, values[:LLTF_BYTES]))
    if not rows:
        raise CaptureFormatError(
            f"{name}: no readable CSI_DATA line (ESP32 CSI text)"
            + (f"; {problems[0][1]}" if problems else "")
        )
    frames = new_frames("esp32", len(rows), 1, 1, _subcarriers())
    for i, (mac, rssi, channel, t_us, values) in enumerate(rows):
        iq = values[1::2].astype(np.float32) + 1j * values[0::2].astype(np.float32)
        frames.h[i, 0, 0] = iq
        frames.mac[i] = mac
        frames.rssi_dbm[i, 0] = rssi if math.isfinite(rssi) else np.nan
        frames.t_ns[i] = t_us * 1000
        if 1 <= channel <= 13:
            frames.freq_mhz[i] = 2407 + 5 * channel
        elif channel == 14:
            frames.freq_mhz[i] = 2484
        else:
            frames.freq_mhz[i] = freq_mhz
    notes: Counter[str] = Counter({"one antenna per packet": len(rows)})
    notes["lines with fewer CSI values than their len"] = short
    return CsiCapture(name, "esp32", [frames], "dBm", problems, notes)
