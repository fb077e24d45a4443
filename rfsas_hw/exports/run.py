"""Reading a backend run log (``rfsas backend --out run.jsonl``) for the exports.

A run log is JSON lines with a ``"record"`` key: ``site`` (the origin on
WGS-84), ``bearing`` (with the sensor's pose), ``fix``, ``assessment`` and
``stats`` (see :class:`~rfsas_hw.backend.service.JsonlSink`). A line that is
not JSON or not a known record is skipped and counted, with its line number
in :attr:`RunLog.errors`: a corrupted line costs only that line.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from rfsas_hw.errors import ConfigError, ExportError
from rfsas_hw.geo import SiteOrigin, site_origin_from_mapping
from rfsas_hw.records import Assessment, Fix

T = TypeVar("T")

__all__ = ["BearingLine", "RunLog", "read_run"]

MAX_ERRORS_KEPT = 20
"""Messages of skipped lines kept for the user (all are counted)."""


@dataclass(frozen=True, slots=True)
class BearingLine:
    """One bearing of a run log with the pose of the sensor that measured it."""

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
    x_m: float
    """Sensor east, metres."""
    y_m: float
    """Sensor north, metres."""


@dataclass
class RunLog:
    """What a run log holds, in file order per kind."""

    source: str
    """File name, for messages."""
    origin: SiteOrigin | None = None
    """The site origin the log carries (None: the log has no ``site`` line)."""
    bearings: list[BearingLine] = field(default_factory=list)
    fixes: list[Fix] = field(default_factory=list)
    assessments: list[Assessment] = field(default_factory=list)
    skipped: Counter[str] = field(default_factory=Counter)
    """Skipped lines by reason."""
    errors: list[str] = field(default_factory=list)
    """The first few skipped lines, with line numbers."""


def _build(cls: type[T], data: dict[str, Any], where: str) -> T:
    """A record dataclass from a JSON mapping: null → NaN, lists → tuples, types checked."""
    values: dict[str, Any] = {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if f.name not in data:
            raise ValueError(f"{where}: missing key {f.name}")
        value = data[f.name]
        kind = str(f.type)
        if kind == "float":
            if value is None:
                value = math.nan
            elif isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"{where}: {f.name} is not a number")
            value = float(value)
        elif kind == "int" and (isinstance(value, bool) or not isinstance(value, int)):
            raise ValueError(f"{where}: {f.name} is not an integer")
        elif kind == "str" and not isinstance(value, str):
            raise ValueError(f"{where}: {f.name} is not text")
        elif kind.startswith("tuple"):
            if not isinstance(value, list):
                raise ValueError(f"{where}: {f.name} is not a list")
            value = tuple(str(v) for v in value)
        values[f.name] = value
    return cls(**values)


def _bearing(data: dict[str, Any], where: str) -> BearingLine:
    try:
        num = {
            k: math.nan if data[k] is None else float(data[k])
            for k in ("azimuth_deg", "sigma_deg", "x_m", "y_m")
        }
        return BearingLine(
            t_ns=int(data["t_ns"]),
            sensor_id=str(data["sensor_id"]),
            emitter=str(data["emitter"]),
            **num,
        )
    except KeyError as err:
        raise ValueError(f"{where}: missing key {err.args[0]}") from None
    except (TypeError, ValueError):
        raise ValueError(f"{where}: a value is not a number") from None


def read_run(path: str | Path) -> RunLog:
    """Read a run log (see the module docstring).

    Raises:
        ExportError: the file cannot be read, or its ``site`` line is invalid.
    """
    p = Path(path)
    run = RunLog(source=str(p))
    try:
        f = p.open("r", encoding="utf-8", errors="replace")
    except OSError as err:
        raise ExportError(f"{p}: cannot read: {err.strerror or err}") from err
    with f:
        for lineno, line in enumerate(f, 1):
            if not line.strip():
                continue
            where = f"{p}: line {lineno}"
            try:
                data = json.loads(line)
                if not isinstance(data, dict):
                    raise ValueError(f"{where}: not a JSON object")
                kind = data.get("record")
                body = {k: v for k, v in data.items() if k != "record"}
                if kind == "site":
                    try:
                        origin = body.get("origin", {})
                        run.origin = site_origin_from_mapping(origin, f"{where}: origin")
                    except ConfigError as err:
                        raise ExportError(str(err)) from err
                elif kind == "bearing":
                    run.bearings.append(_bearing(body, where))
                elif kind == "fix":
                    run.fixes.append(_build(Fix, body, where))
                elif kind == "assessment":
                    run.assessments.append(_build(Assessment, body, where))
                elif kind == "stats":
                    continue
                else:
                    raise ValueError(f"{where}: unknown record {kind!r}")
            except (ValueError, TypeError) as err:
                reason = "not JSON" if isinstance(err, json.JSONDecodeError) else "bad record"
                run.skipped[reason] += 1
                if len(run.errors) < MAX_ERRORS_KEPT:
                    run.errors.append(f"{where}: not JSON" if reason == "not JSON" else str(err))
    return run
