"""Bearing writers: JSONL and CSV files as listeners of the bearing stream.

Each line or row is one :class:`~rfsas_hw.records.Bearing` with the keys
``t_ns, sensor_id, azimuth_deg, sigma_deg, snr_db, channel, emitter,
relative_deg``. Azimuths are compass degrees; the emitter is the hashed id.
A value a unit does not measure (the SNR of a Doppler or agrelo unit) is
``null`` in JSONL and an empty cell in CSV: bare ``NaN`` is not JSON.

A file is written as the bearings come (a live run's output can be followed
while it grows); ``-`` is standard output. Whether an existing file may be
replaced is the caller's decision (:func:`~rfsas_hw.outpaths.check_output`).
A write that fails (disk full, I/O error) does not stop the sensor: the
writer counts what it lost and keeps the first error for the run's summary.
"""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path
from typing import IO, Literal

import numpy as np

from rfsas_hw.errors import ConfigError
from rfsas_hw.outpaths import STDIO
from rfsas_hw.records import BearingBatch, emitter_hex

Format = Literal["jsonl", "csv"]
FIELDS = (
    "t_ns",
    "sensor_id",
    "azimuth_deg",
    "sigma_deg",
    "snr_db",
    "channel",
    "emitter",
    "relative_deg",
)


def format_for(path: str | Path, fmt: str | None = None) -> Format:
    """The output format named by ``fmt``, or by the file suffix (.jsonl/.json/.csv).

    Raises:
        ConfigError: unknown format or suffix.
    """
    name = (fmt or Path(path).suffix.lstrip(".")).lower()
    if name in ("jsonl", "json", "ndjson"):
        return "jsonl"
    if name == "csv":
        return "csv"
    raise ConfigError(
        f"{path}: cannot tell the output format; use a .jsonl or .csv name or --format"
    )


def _column(values: np.ndarray, digits: int) -> list[float | None]:
    """Rounded values, with None where a value is not finite (unknown)."""
    out: list[float | None] = np.round(values, digits).tolist()
    if not np.isfinite(values).all():
        out = [v if v is not None and math.isfinite(v) else None for v in out]
    return out


def _rows(batch: BearingBatch) -> list[tuple[object, ...]]:
    return list(
        zip(
            batch.t_ns.tolist(),
            [batch.sensor_id] * len(batch),
            _column(batch.azimuth_deg, 4),
            _column(batch.sigma_deg, 4),
            _column(batch.snr_db, 2),
            batch.channel.tolist(),
            [emitter_hex(e) for e in batch.emitter.tolist()],
            _column(batch.relative_deg, 4),
            strict=True,
        )
    )


class BearingWriter:
    """Write bearings to a JSONL or CSV file, standard output (``-``), or an open stream.

    Args:
        target: a path, ``-`` for standard output, or an open text stream (not
            closed by :meth:`close`).
        fmt: ``jsonl`` or ``csv``; by default from the file suffix (``jsonl`` for ``-``).

    Raises:
        ConfigError: unknown format, or the file cannot be created.
    """

    def __init__(self, target: str | Path | IO[str], fmt: str | None = None) -> None:
        self.name = "stream"
        if isinstance(target, str | Path) and str(target) == STDIO:
            self.format: Format = format_for("stdout", fmt or "jsonl")
            self._stream: IO[str] = sys.stdout
            self._owned = False
            self.name = "stdout"
        elif isinstance(target, str | Path):
            self.format = format_for(target, fmt)
            try:
                self._stream = Path(target).open(  # noqa: SIM115 - closed in close()
                    "w", encoding="utf-8", newline=""
                )
            except OSError as err:
                raise ConfigError(f"{target}: cannot write: {err.strerror or err}") from err
            self._owned = True
            self.name = str(target)
        else:
            self.format = format_for("stream", fmt or "jsonl")
            self._stream = target
            self._owned = False
        self.written = 0
        """Bearings handed to the file (lost ones excluded)."""
        self.lost = 0
        """Bearings that could not be written."""
        self.error: str | None = None
        """The first write error (``No space left on device``), or None."""
        self._csv = csv.writer(self._stream, lineterminator="\n") if self.format == "csv" else None
        if self._csv is not None:
            self._guard(lambda: self._csv.writerow(FIELDS) if self._csv else None, 0)

    @property
    def failed(self) -> bool:
        """True when something could not be written (the output is incomplete)."""
        return self.error is not None

    def _guard(self, write: object, rows: int) -> bool:
        if self.error is not None:
            self.lost += rows
            return False
        try:
            write()  # type: ignore[operator]
        except (OSError, ValueError) as err:
            # ValueError: writing to a stream closed under us (stdout of a dead pipe)
            self.error = str(getattr(err, "strerror", None) or err)
            self.lost += rows
            return False
        return True

    def on_bearings(self, batch: BearingBatch) -> None:
        """Write every bearing of ``batch``; a failed write is counted, not raised."""
        if len(batch) == 0:
            return
        rows = _rows(batch)
        if self._csv is not None:
            csv_writer = self._csv
            ok = self._guard(lambda: csv_writer.writerows(rows), len(rows))
        else:
            text = "".join(json.dumps(dict(zip(FIELDS, r, strict=True))) + "\n" for r in rows)
            ok = self._guard(lambda: self._stream.write(text), len(rows))
        if ok:
            self.written += len(rows)

    def counters(self) -> dict[str, int]:
        """``written`` and ``lost`` bearings, for the run summary."""
        return {"written": self.written, "lost": self.lost}

    def close(self) -> None:
        """Flush, and close the file if this writer opened it; a failure is recorded
        (:attr:`error`), not raised. Idempotent."""
        self._guard(self._stream.flush, 0)
        if self._owned and not self._stream.closed:
            # a failed flush leaves the data in the buffer; closing would retry it
            # and raise again
            try:
                self._stream.close()
            except (OSError, ValueError) as err:
                if self.error is None:
                    self.error = str(getattr(err, "strerror", None) or err)
