"""Export recorded rfsas runs (JSON lines) to an MCAP file or a rosbag2 directory.

Reads what the commands write:

- a backend run log (``rfsas backend --out run.jsonl``): ``"record"`` lines
  ``fix``, ``assessment``, ``bearing`` (with the sensor's ``x_m``, ``y_m``,
  ``heading_deg``), ``site`` and ``stats``;
- a bearings file (``rfsas replay/live --out bearings.jsonl``): one bearing per
  line without a ``record`` key and without a pose (give poses by sensor id).

Consecutive bearings of one sensor within :data:`BATCH_GAP_NS` become one
``BearingArray``; the fix and assessment lines one backend step wrote become
one step. Events of all inputs are merged in time order and go through the
same :class:`~rfsas_hw.ros2.sink.BackendScene` as a live run, so an export
and a live recording of one run carry the same messages. A line that is not
JSON or not a valid record is skipped and counted with its line number.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from rfsas_hw.errors import ConfigError, DataFormatError
from rfsas_hw.records import Assessment, BearingBatch, Fix, Pose
from rfsas_hw.ros2.bag import RecordFormat, open_recording
from rfsas_hw.ros2.scene import SceneBuilder, SceneConfig
from rfsas_hw.ros2.sink import BackendScene, SceneSink

BATCH_GAP_NS = 100_000_000
"""Bearings of one sensor closer than this to the batch's first become one array, ns."""
MAX_ERRORS_KEPT = 20


@dataclass(frozen=True, slots=True)
class _BearingRow:
    t_ns: int
    sensor_id: str
    azimuth_deg: float
    sigma_deg: float
    snr_db: float
    channel: int
    emitter: int
    relative_deg: float
    pose: Pose | None


@dataclass(slots=True)
class _Step:
    t_ns: int
    fixes: list[Fix] = field(default_factory=list)
    assessments: list[Assessment] = field(default_factory=list)


@dataclass
class ExportResult:
    """What an export wrote and skipped."""

    messages: int = 0
    """Messages written."""
    counts: dict[str, int] = field(default_factory=dict)
    """Messages by topic."""
    bearings: int = 0
    fixes: int = 0
    assessments: int = 0
    skipped: Counter[str] = field(default_factory=Counter)
    """Skipped lines by reason."""
    errors: list[str] = field(default_factory=list)
    """The first skipped lines, with file and line number."""
    no_pose: set[str] = field(default_factory=set)
    """Sensors whose bearings had no pose."""


def _num(data: Mapping[str, Any], key: str, where: str) -> float:
    if key not in data:
        raise ValueError(f"{where}: missing key {key}")
    value = data[key]
    if value is None:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{where}: {key} is not a number")
    return float(value)


def _int(data: Mapping[str, Any], key: str, where: str) -> int:
    value = data.get(key)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{where}: {key} is not an integer")
    return value


def _record(cls: type[Any], data: Mapping[str, Any], where: str) -> Any:
    """A Fix or Assessment from its JSON mapping (null → NaN, lists → tuples)."""
    values: dict[str, Any] = {}
    for f in fields(cls):
        kind = str(f.type)
        if kind == "float":
            values[f.name] = _num(data, f.name, where)
        elif kind == "int":
            values[f.name] = _int(data, f.name, where)
        elif kind == "bool":
            if not isinstance(data.get(f.name), bool):
                raise ValueError(f"{where}: {f.name} is not true/false")
            values[f.name] = data[f.name]
        elif kind == "str":
            if not isinstance(data.get(f.name), str):
                raise ValueError(f"{where}: {f.name} is not text")
            values[f.name] = data[f.name]
        else:
            items = data.get(f.name)
            if not isinstance(items, list) or not all(isinstance(v, str) for v in items):
                raise ValueError(f"{where}: {f.name} is not a list of text")
            values[f.name] = tuple(items)
    return cls(**values)


def _bearing(data: Mapping[str, Any], where: str, poses: Mapping[str, Pose]) -> _BearingRow:
    sensor_id = data.get("sensor_id")
    emitter = data.get("emitter")
    if not isinstance(sensor_id, str) or not isinstance(emitter, str):
        raise ValueError(f"{where}: sensor_id and emitter must be text")
    try:
        emitter_int = int(emitter, 16)
    except ValueError:
        raise ValueError(f"{where}: emitter {emitter!r} is not hex") from None
    pose = poses.get(sensor_id)
    if pose is None and "x_m" in data:
        x, y = _num(data, "x_m", where), _num(data, "y_m", where)
        heading = _num(data, "heading_deg", where) if "heading_deg" in data else math.nan
        if math.isfinite(x) and math.isfinite(y):
            pose = Pose(x, y, heading if math.isfinite(heading) else 0.0)
    return _BearingRow(
        t_ns=_int(data, "t_ns", where),
        sensor_id=sensor_id,
        azimuth_deg=_num(data, "azimuth_deg", where),
        sigma_deg=_num(data, "sigma_deg", where),
        snr_db=_num(data, "snr_db", where) if "snr_db" in data else math.nan,
        channel=_int(data, "channel", where) if "channel" in data else 0,
        emitter=emitter_int,
        relative_deg=_num(data, "relative_deg", where) if "relative_deg" in data else math.nan,
        pose=pose,
    )


def _batch(rows: list[_BearingRow]) -> BearingBatch:
    return BearingBatch(
        sensor_id=rows[0].sensor_id,
        t_ns=np.array([r.t_ns for r in rows], np.int64),
        azimuth_deg=np.array([r.azimuth_deg for r in rows]),
        sigma_deg=np.array([r.sigma_deg for r in rows]),
        snr_db=np.array([r.snr_db for r in rows]),
        channel=np.array([r.channel for r in rows], np.int16),
        emitter=np.array([r.emitter for r in rows], np.uint64),
        relative_deg=np.array([r.relative_deg for r in rows]),
    )


Event = tuple[int, int, Any]
"""(time ns, order of reading, a (BearingBatch, pose) pair or a _Step)."""


def read_events(
    path: str | Path, poses: Mapping[str, Pose], result: ExportResult
) -> Iterator[tuple[int, Any]]:
    """The bearing batches and backend steps of one JSONL file, in file order.

    Raises:
        DataFormatError: the file cannot be read.
    """
    p = Path(path)
    try:
        f = p.open("r", encoding="utf-8", errors="replace")
    except OSError as err:
        raise DataFormatError(f"{p}: cannot read: {err.strerror or err}") from err
    pending: list[_BearingRow] = []
    step: _Step | None = None

    def flush_bearings() -> Iterator[tuple[int, Any]]:
        if pending:
            batch = _batch(pending)
            yield int(batch.t_ns.max()), (batch, pending[0].pose)
            pending.clear()

    with f:
        for lineno, line in enumerate(f, 1):
            if not line.strip():
                continue
            where = f"{p}: line {lineno}"
            try:
                data = json.loads(line)
                if not isinstance(data, dict):
                    raise ValueError(f"{where}: not a JSON object")
                kind = data.get("record", "bearing")
                if kind == "bearing":
                    row = _bearing(data, where, poses)
                    if pending and (
                        row.sensor_id != pending[0].sensor_id
                        or row.pose != pending[0].pose
                        or abs(row.t_ns - pending[0].t_ns) > BATCH_GAP_NS
                    ):
                        yield from flush_bearings()
                    pending.append(row)
                    continue
                if kind == "fix":
                    fix = _record(Fix, data, where)
                    if step is not None and step.assessments:
                        yield step.t_ns, step
                        step = None
                    if step is None:
                        step = _Step(fix.t_ns)
                    step.fixes.append(fix)
                    step.t_ns = max(step.t_ns, fix.t_ns)
                elif kind == "assessment":
                    a = _record(Assessment, data, where)
                    if step is not None and step.assessments and step.assessments[0].t_ns != a.t_ns:
                        yield step.t_ns, step
                        step = None
                    if step is None:
                        step = _Step(a.t_ns)
                    step.assessments.append(a)
                    step.t_ns = a.t_ns
                elif kind in ("stats", "site"):
                    continue
                else:
                    raise ValueError(f"{where}: unknown record {kind!r}")
            except (ValueError, TypeError) as err:
                reason = "not JSON" if isinstance(err, json.JSONDecodeError) else "bad record"
                result.skipped[reason] += 1
                if len(result.errors) < MAX_ERRORS_KEPT:
                    result.errors.append(f"{where}: not JSON" if reason == "not JSON" else str(err))
    yield from flush_bearings()
    if step is not None:
        yield step.t_ns, step


def export_runs(
    runs: list[Path] | list[str],
    out: str | Path,
    fmt: RecordFormat,
    *,
    poses: Mapping[str, Pose] | None = None,
    storage: str = "sqlite3",
    scene: SceneConfig | None = None,
) -> ExportResult:
    """Write the runs in ``runs`` as one MCAP file or rosbag2 directory at ``out``.

    Args:
        runs: JSONL files (backend run logs and/or bearings files).
        out: the MCAP file (replaced if it exists), or the rosbag2 directory (must be new).
        fmt: ``mcap`` or ``rosbag2``.
        poses: sensor poses by id, for bearings that carry none (they win over a
            pose in the file).
        storage: rosbag2 storage plugin, ``sqlite3`` or ``mcap``.
        scene: frame names and drawing settings.

    Raises:
        DataFormatError: an input cannot be read.
        ConfigError: ``out`` is an input, the rosbag2 directory exists, or the
            output cannot be written.
        MissingDependencyError: the ros2 extra is not installed.
    """
    poses = dict(poses or {})
    target = Path(out).resolve()
    for path in runs:
        if Path(path).resolve() == target:
            raise ConfigError(f"{out} is also an input; refusing to write over it")
    result = ExportResult()
    events: list[Event] = []
    for path in runs:
        for t_ns, item in read_events(path, poses, result):
            events.append((t_ns, len(events), item))
    events.sort(key=lambda e: (e[0], e[1]))
    sink = SceneSink([open_recording(out, fmt, storage=storage)], SceneBuilder(scene))
    stations: dict[str, Pose] = {}
    backend = BackendScene(sink, stations=lambda: stations)
    try:
        for _, _, item in events:
            if isinstance(item, _Step):
                backend.on_results(item.fixes, item.assessments)
                result.fixes += len(item.fixes)
                result.assessments += len(item.assessments)
                continue
            batch, pose = item
            result.bearings += len(batch)
            if pose is None:
                result.no_pose.add(batch.sensor_id)
            else:
                stations[batch.sensor_id] = pose
            sink.emit(sink.builder.bearings(batch, pose))
    finally:
        sink.close()
    result.counts = dict(sink.counts)
    result.messages = sum(sink.counts.values())
    return result
