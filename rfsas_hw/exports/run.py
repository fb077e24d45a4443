"""Reading a backend run log (``rfsas backend --out run.jsonl``) for the exports.

A run log is JSON lines with a ``"record"`` key: ``site`` (the origin on
WGS-84), ``bearing`` (with the sensor's pose), ``fix``, ``assessment`` and
``stats`` (see :class:`~rfsas_hw.backend.service.JsonlSink`). A line that is
not JSON or not a known record is skipped and counted, with its line number
in :attr:`RunLog.errors`: a corrupted line costs only that line (a number out
of range, a time before 1970 or after 2038, nesting too deep for the parser).
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from collections import Counter
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from rfsas_hw.errors import ConfigError, DataFormatError, ExportError
from rfsas_hw.geo import SiteOrigin, site_origin_from_mapping
from rfsas_hw.records import Assessment, Fix

T = TypeVar("T")

__all__ = ["BearingLine", "RunLog", "RunRecord", "SiteLine", "iter_records", "read_run"]

MAX_ABS = 1.0e9
"""A number of a record beyond this (metres, degrees, dB, m²) is corrupt, not data."""
MAX_T_NS = (2**31 - 1) * 1_000_000_000
"""The last time a record may carry: ROS 2 time counts seconds in 32 bits (2038)."""
MAX_ERRORS_KEPT = 20
_EMITTER = re.compile(r"[0-9a-fA-F]{1,16}")
"""A hashed emitter id as written: a 64-bit number in hex."""
"""Messages of skipped lines kept for the user (all are counted)."""


@dataclass(frozen=True, slots=True)
class BearingLine:
    """One bearing of a run log, with the pose of the sensor that measured it if known."""

    t_ns: int
    """Capture time, UTC ns."""
    sensor_id: str
    """The measuring sensor."""
    emitter: str
    """Hashed emitter id (hex)."""
    azimuth_deg: float
    """Compass azimuth of the emitter from the sensor, degrees."""
    sigma_deg: float
    """One-sigma error of the azimuth, degrees."""
    x_m: float = math.nan
    """Sensor east, metres (NaN: the line has no pose, as in a bearings file)."""
    y_m: float = math.nan
    """Sensor north, metres (NaN: no pose)."""
    heading_deg: float = math.nan
    """Sensor heading, compass degrees (NaN: not given)."""
    snr_db: float = math.nan
    """Signal-to-noise ratio, dB (NaN: not given)."""
    channel: int = 0
    """IEEE channel (0: not given)."""
    relative_deg: float = math.nan
    """Azimuth relative to the sensor's heading, degrees (NaN: not given)."""


@dataclass(frozen=True, slots=True)
class SiteLine:
    """A ``site`` line: its ``origin`` mapping as written (checked by who needs it)."""

    where: str
    """File and line number, for messages."""
    origin: Any
    """The ``origin`` value of the line."""


RunRecord = BearingLine | Fix | Assessment | SiteLine
"""What :func:`iter_records` yields."""


@dataclass
class RunLog:
    """What a run log holds, in file order per kind."""

    source: str
    """File name, for messages."""
    origin: SiteOrigin | None = None
    """The site origin the log carries (None: the log has no ``site`` line)."""

    def origin_or(self, origin: SiteOrigin | None) -> SiteOrigin:
        """``origin`` when given, else the log's own site origin.

        Raises:
            ExportError: neither is there.
        """
        where = origin or self.origin
        if where is None:
            raise ExportError(
                f"{self.source}: the log has no site origin; give --origin LAT,LON[,HEIGHT] "
                "(or run the backend with a site origin)"
            )
        return where

    bearings: list[BearingLine] = field(default_factory=list)
    fixes: list[Fix] = field(default_factory=list)
    assessments: list[Assessment] = field(default_factory=list)
    skipped: Counter[str] = field(default_factory=Counter)
    """Skipped lines by reason."""
    errors: list[str] = field(default_factory=list)
    """The first few skipped lines, with line numbers."""


def _num(data: Mapping[str, Any], key: str, where: str) -> float:
    if key not in data:
        raise ValueError(f"{where}: missing key {key}")
    value = data[key]
    if value is None:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{where}: {key} is not a number")
    number = float(value)
    if not abs(number) <= MAX_ABS:
        raise ValueError(f"{where}: {key} {value!r} is out of range (|value| <= {MAX_ABS:g})")
    return number


def _int(data: Mapping[str, Any], key: str, where: str) -> int:
    if key not in data:
        raise ValueError(f"{where}: missing key {key}")
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{where}: {key} is not an integer")
    if key == "t_ns" and not 0 <= value <= MAX_T_NS:
        raise ValueError(f"{where}: t_ns {value} is not a time from 1970 to 2038")
    if not abs(value) <= MAX_T_NS:
        raise ValueError(f"{where}: {key} {value} is out of range")
    return value


def _record(cls: type[T], data: Mapping[str, Any], where: str) -> T:
    """A record dataclass from a JSON mapping: null → NaN, lists → tuples, types checked."""
    values: dict[str, Any] = {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if f.name not in data:
            raise ValueError(f"{where}: missing key {f.name}")
        value = data[f.name]
        kind = str(f.type)
        if kind == "float":
            value = _num(data, f.name, where)
        elif kind == "int":
            value = _int(data, f.name, where)
        elif kind == "bool" and not isinstance(value, bool):
            raise ValueError(f"{where}: {f.name} is not true/false")
        elif kind == "str" and not isinstance(value, str):
            raise ValueError(f"{where}: {f.name} is not text")
        elif kind.startswith("tuple"):
            if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
                raise ValueError(f"{where}: {f.name} is not a list of text")
            value = tuple(value)
        values[f.name] = value
    return cls(**values)


def _bearing(data: Mapping[str, Any], where: str) -> BearingLine:
    sensor_id = data.get("sensor_id")
    emitter = data.get("emitter")
    if not isinstance(sensor_id, str) or not isinstance(emitter, str):
        raise ValueError(f"{where}: sensor_id and emitter must be text")
    if _EMITTER.fullmatch(emitter) is None:
        raise ValueError(f"{where}: emitter {emitter!r} is not 1 to 16 hex digits")

    def optional(key: str) -> float:
        return _num(data, key, where) if key in data else math.nan

    return BearingLine(
        t_ns=_int(data, "t_ns", where),
        sensor_id=sensor_id,
        emitter=emitter,
        azimuth_deg=_num(data, "azimuth_deg", where),
        sigma_deg=_num(data, "sigma_deg", where),
        x_m=optional("x_m"),
        y_m=optional("y_m"),
        heading_deg=optional("heading_deg"),
        snr_db=optional("snr_db"),
        channel=_int(data, "channel", where) if "channel" in data else 0,
        relative_deg=optional("relative_deg"),
    )


def iter_records(
    path: str | Path,
    skipped: Counter[str],
    errors: list[str],
    *,
    default_record: str | None = None,
) -> Iterator[RunRecord]:
    """The records of a JSON-lines file in file order; ``stats`` lines are passed over.

    A line that is not JSON or not a valid record is counted in ``skipped``
    (by reason) and, while there is room, named in ``errors`` with its line
    number. ``default_record`` is the kind of a line without a ``record`` key
    (``"bearing"`` for a bearings file; None: such a line is a bad record).

    Raises:
        DataFormatError: the file cannot be read.
    """
    p = Path(path)
    try:
        f = p.open("r", encoding="utf-8", errors="replace")
    except OSError as err:
        raise DataFormatError(f"{p}: cannot read: {err.strerror or err}") from err
    with f:
        for lineno, line in enumerate(f, 1):
            if not line.strip():
                continue
            where = f"{p}: line {lineno}"
            record: RunRecord
            try:
                data = json.loads(line)
                if not isinstance(data, dict):
                    raise ValueError(f"{where}: not a JSON object")
                kind = data.get("record", default_record)
                if kind == "bearing":
                    record = _bearing(data, where)
                elif kind == "fix":
                    record = _record(Fix, data, where)
                elif kind == "assessment":
                    record = _record(Assessment, data, where)
                elif kind == "site":
                    record = SiteLine(where, data.get("origin", {}))
                elif kind == "stats":
                    continue
                else:
                    raise ValueError(f"{where}: unknown record {kind!r}")
            except RecursionError:
                # nesting deeper than the parser's stack: no record of ours nests so
                skipped["not JSON"] += 1
                if len(errors) < MAX_ERRORS_KEPT:
                    errors.append(f"{where}: nested too deeply")
                continue
            except (ValueError, TypeError) as err:
                reason = "not JSON" if isinstance(err, json.JSONDecodeError) else "bad record"
                skipped[reason] += 1
                if len(errors) < MAX_ERRORS_KEPT:
                    errors.append(f"{where}: not JSON" if reason == "not JSON" else str(err))
                continue
            yield record


def read_run(path: str | Path) -> RunLog:
    """Read a run log (see the module docstring).

    Raises:
        ExportError: the file cannot be read, or its ``site`` line is invalid.
    """
    run = RunLog(source=str(Path(path)))
    try:
        # a bearings file of replay/live has no record key: its lines are bearings
        for record in iter_records(path, run.skipped, run.errors, default_record="bearing"):
            if isinstance(record, BearingLine):
                run.bearings.append(record)
            elif isinstance(record, Fix):
                run.fixes.append(record)
            elif isinstance(record, Assessment):
                run.assessments.append(record)
            else:
                try:
                    run.origin = site_origin_from_mapping(record.origin, f"{record.where}: origin")
                except ConfigError as err:
                    raise ExportError(str(err)) from err
    except DataFormatError as err:
        raise ExportError(str(err)) from err
    return run
