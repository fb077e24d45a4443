"""Turntable sample files: ``angle_deg,rssi1_dbm,rssi2_dbm[,channel]`` CSV.

Errors name the file and line; a missing column, a non-number or an empty
file is rejected as a whole (a calibration from half a file would be wrong
without saying so).
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from rfsas_hw.config import read_text_input
from rfsas_hw.errors import DataFormatError
from rfsas_hw.rf.synth import TurntableSamples

REQUIRED = ("angle_deg", "rssi1_dbm", "rssi2_dbm")
OPTIONAL = ("channel",)
MAX_CHANNEL = 255
"""Highest channel number (IEEE channels of 2.4/5/6 GHz and BLE are below it; 0: unknown)."""


def read_samples_csv(path: str | Path) -> TurntableSamples:
    """Read a turntable CSV with a header row.

    Raises:
        DataFormatError: unreadable or empty file, missing column, a value
            that is not a number (with its line and column).
    """
    p = Path(path)
    text = read_text_input(p, "CSV", error=DataFormatError)
    try:
        return _parse_samples(p, text)
    except csv.Error as err:
        raise DataFormatError(f"{p}: not a CSV file: {err}") from err


def _parse_samples(p: Path, text: str) -> TurntableSamples:
    reader = csv.reader(io.StringIO(text, newline=""))
    header = next(reader, None)
    if header is None or not any(h.strip() for h in header):
        raise DataFormatError(f"{p}: empty file (expected a header {','.join(REQUIRED)}[,channel])")
    names = [h.strip() for h in header]
    for col in REQUIRED:
        if col not in names:
            raise DataFormatError(
                f"{p}: line 1: missing column {col!r} (header is {','.join(names)})"
            )
    unknown = [n for n in names if n not in REQUIRED + OPTIONAL]
    if unknown:
        raise DataFormatError(f"{p}: line 1: unknown column {unknown[0]!r}")
    idx = {n: names.index(n) for n in names}
    rows: list[tuple[float, float, float, int]] = []
    for line_no, record in enumerate(reader, start=2):
        if not record or all(not f.strip() for f in record):
            continue
        if len(record) != len(names):
            raise DataFormatError(
                f"{p}: line {line_no}: {len(record)} fields, header has {len(names)}"
            )
        values = []
        for col in REQUIRED:
            text = record[idx[col]].strip()
            try:
                value = float(text)
            except ValueError as err:
                raise DataFormatError(
                    f"{p}: line {line_no}: column {col!r}: {text!r} is not a number"
                ) from err
            if not math.isfinite(value):
                raise DataFormatError(
                    f"{p}: line {line_no}: column {col!r}: {text!r} is not finite"
                )
            values.append(value)
        channel = 0
        if "channel" in idx:
            text = record[idx["channel"]].strip()
            try:
                channel = int(text) if text else 0
            except ValueError as err:
                raise DataFormatError(
                    f"{p}: line {line_no}: column 'channel': {text!r} is not an integer"
                ) from err
            if not 0 <= channel <= MAX_CHANNEL:
                raise DataFormatError(
                    f"{p}: line {line_no}: column 'channel': {channel} is not a channel "
                    f"number (0-{MAX_CHANNEL})"
                )
        rows.append((values[0], values[1], values[2], channel))
    if not rows:
        raise DataFormatError(f"{p}: no samples after the header")
    arr = np.array([r[:3] for r in rows], dtype=np.float64)
    return TurntableSamples(
        angle_deg=arr[:, 0],
        rssi1_dbm=arr[:, 1],
        rssi2_dbm=arr[:, 2],
        channel=np.array([r[3] for r in rows], dtype=np.int16),
    )


def write_samples_csv(path: str | Path, samples: TurntableSamples) -> None:
    """Write samples in the format :func:`read_samples_csv` reads."""
    with Path(path).open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow([*REQUIRED, "channel"])
        for a, r1, r2, ch in zip(
            samples.angle_deg, samples.rssi1_dbm, samples.rssi2_dbm, samples.channel, strict=True
        ):
            writer.writerow([f"{a:g}", f"{r1:g}", f"{r2:g}", int(ch)])
