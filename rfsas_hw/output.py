"""Bearing writers: JSONL and CSV files as listeners of the bearing stream.

Each line or row is one :class:`~rfsas_hw.records.Bearing` with the keys
``t_ns, sensor_id, azimuth_deg, sigma_deg, snr_db, channel, emitter,
relative_deg``. Azimuths are compass degrees; the emitter is the hashed id.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import IO, Literal

import numpy as np

from rfsas_hw.errors import ConfigError
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


def _rows(batch: BearingBatch) -> list[tuple[object, ...]]:
    return list(
        zip(
            batch.t_ns.tolist(),
            [batch.sensor_id] * len(batch),
            np.round(batch.azimuth_deg, 4).tolist(),
            np.round(batch.sigma_deg, 4).tolist(),
            np.round(batch.snr_db, 2).tolist(),
            batch.channel.tolist(),
            [emitter_hex(e) for e in batch.emitter.tolist()],
            np.round(batch.relative_deg, 4).tolist(),
            strict=True,
        )
    )


class BearingWriter:
    """Append bearings to a JSONL or CSV file (or an open text stream).

    Args:
        target: a path, or an open text stream (not closed by :meth:`close`).
        fmt: ``jsonl`` or ``csv``; by default from the file suffix.
    """

    def __init__(self, target: str | Path | IO[str], fmt: str | None = None) -> None:
        if isinstance(target, str | Path):
            self.format: Format = format_for(target, fmt)
            try:
                self._stream: IO[str] = Path(target).open(  # noqa: SIM115 - closed in close()
                    "w", encoding="utf-8", newline=""
                )
            except OSError as err:
                raise ConfigError(f"{target}: cannot write: {err.strerror or err}") from err
            self._owned = True
        else:
            self.format = format_for("stream", fmt or "jsonl")
            self._stream = target
            self._owned = False
        self._csv = csv.writer(self._stream, lineterminator="\n") if self.format == "csv" else None
        if self._csv is not None:
            self._csv.writerow(FIELDS)
        self.written = 0

    def on_bearings(self, batch: BearingBatch) -> None:
        """Write every bearing of ``batch``."""
        if len(batch) == 0:
            return
        rows = _rows(batch)
        if self._csv is not None:
            self._csv.writerows(rows)
        else:
            self._stream.write(
                "".join(json.dumps(dict(zip(FIELDS, r, strict=True))) + "\n" for r in rows)
            )
        self.written += len(rows)

    def close(self) -> None:
        """Flush, and close the file if this writer opened it."""
        self._stream.flush()
        if self._owned:
            self._stream.close()
