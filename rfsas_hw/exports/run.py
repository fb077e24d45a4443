"""Reading a backend run log (``rfsas backend --out run.jsonl``) for the exports.

A run log is JSON lines with a ``"record"`` key: ``site`` (the origin on
WGS-84), ``bearing`` (with the sensor's pose), ``fix``, ``assessment`` and
``stats`` (see :class:`~rfsas_hw.backend.service.JsonlSink`). A line that is
not JSON or not a known record is skipped and counted, with its line number
in :attr:`RunLog.errors`: a corrupted line costs only that line (a number out
of range, a time before 1970 or after 2038, nesting too deep for the parser).

The log is read line by line (:meth:`RunLog.records`): an export holds the
record it is on, not the file, whatever the log's length.
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

__all__ = [
    "BearingLine",
    "LoadedRun",
    "RunLog",
    "RunRecord",
    "SiteLine",
    "iter_records",
    "read_run",
]

MAX_ABS = 1.0e9
"""A number of a record beyond this (metres, degrees, dB, m²) is corrupt, not data."""
MAX_T_NS = (2**31 - 1) * 1_000_000_000
"""The last time a record may carry: ROS 2 time counts seconds in 32 bits (2038)."""
MAX_ERRORS_KEPT = 20
"""Messages of skipped lines kept for the user (all are counted)."""
_EMITTER = re.compile(r"[0-9a-fA-F]{1,16}")
"""A hashed emitter id as written: a 64-bit number in hex."""


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
    """A run log read record by record: its site origin and what was skipped so far.

    :meth:`records` streams the file (nothing but the current line is kept),
    so a log of any length is read in bounded memory; the skip counters fill
    as it goes.
    """

    source: str
    """File name, for messages."""
    origin: SiteOrigin | None = None
    """The site origin the log carries (None: no ``site`` line read so far)."""
    skipped: Counter[str] = field(default_factory=Counter)
    """Skipped lines by reason."""
    errors: list[str] = field(default_factory=list)
    """The first few skipped lines, with line numbers."""
    origin_read: bool = False
    """True once every ``site`` line was seen (:meth:`records` or :meth:`scan_origin` ran)."""

    def origin_or(self, origin: SiteOrigin | None) -> SiteOrigin:
        """``origin`` when given, else the log's own site origin (found by
        :meth:`scan_origin` if the log was not read yet).

        Raises:
            ExportError: neither is there, the file cannot be read, or a
                ``site`` line is invalid.
        """
        if origin is not None:
            return origin
        if not self.origin_read:
            self.scan_origin()
        if self.origin is None:
            raise ExportError(
                f"{self.source}: the log has no site origin; give --origin LAT,LON[,HEIGHT] "
                "(or run the backend with a site origin)"
            )
        return self.origin

    def _site(self, line: SiteLine) -> SiteOrigin:
        try:
            return site_origin_from_mapping(line.origin, f"{line.where}: origin")
        except ConfigError as err:
            raise ExportError(str(err)) from err

    def scan_origin(self) -> SiteOrigin | None:
        """Find the log's site origin (the last ``site`` line's) ahead of :meth:`records`.

        A first pass that parses only the lines that can be ``site`` records
        (their text names it, or has a JSON escape); it counts nothing: the
        skipped lines are counted once, by :meth:`records`.

        Raises:
            ExportError: the file cannot be read, or a ``site`` line is invalid.
        """
        p = Path(self.source)
        try:
            f = p.open("r", encoding="utf-8", errors="replace")
        except OSError as err:
            raise ExportError(f"{p}: cannot read: {err.strerror or err}") from err
        with f:
            for lineno, line in enumerate(f, 1):
                if "site" not in line and "\\u" not in line:
                    continue
                try:
                    data = json.loads(line)
                except (ValueError, RecursionError):
                    continue
                if isinstance(data, dict) and data.get("record") == "site":
                    self.origin = self._site(
                        SiteLine(f"{p}: line {lineno}", data.get("origin", {}))
                    )
        self.origin_read = True
        return self.origin

    def records(self) -> Iterator[BearingLine | Fix | Assessment]:
        """The log's bearings, fixes and assessments in file order, read as they are taken.

        A ``site`` line sets :attr:`origin`; a bad line is counted in
        :attr:`skipped` and :attr:`errors`. A bearings file of replay/live
        (lines without a ``record`` key) is read as bearings.

        Raises:
            ExportError: the file cannot be read, or a ``site`` line is invalid.
        """
        try:
            for record in iter_records(
                self.source, self.skipped, self.errors, default_record="bearing"
            ):
                if isinstance(record, SiteLine):
                    self.origin = self._site(record)
                else:
                    yield record
        except DataFormatError as err:
            raise ExportError(str(err)) from err
        self.origin_read = True


@dataclass
class LoadedRun(RunLog):
    """A run log read whole (:func:`read_run`): its records in file order per kind.

    Small logs and tests only; the exports stream :meth:`RunLog.records`.
    """

    bearings: list[BearingLine] = field(default_factory=list)
    fixes: list[Fix] = field(default_factory=list)
    assessments: list[Assessment] = field(default_factory=list)


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


def read_run(path: str | Path) -> LoadedRun:
    """Read a whole run log into memory (see the module docstring).

    Raises:
        ExportError: the file cannot be read, or its ``site`` line is invalid.
    """
    run = LoadedRun(source=str(Path(path)))
    for record in run.records():
        if isinstance(record, BearingLine):
            run.bearings.append(record)
        elif isinstance(record, Fix):
            run.fixes.append(record)
        else:
            run.assessments.append(record)
    return run
