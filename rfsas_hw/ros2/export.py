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

The inputs are read record by record and the events put in time order by an
:class:`~rfsas_hw.exports.spill.ExternalSort` (sorted runs in temporary files,
merged), so memory holds the sort's budget and the open batch, not the logs.
"""

from __future__ import annotations

import math
import pickle
from collections import Counter
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rfsas_hw.errors import ConfigError
from rfsas_hw.exports.run import BearingLine, iter_records
from rfsas_hw.exports.spill import ExternalSort
from rfsas_hw.records import Assessment, BearingBatch, Fix, Pose
from rfsas_hw.ros2.bag import RecordFormat, open_recording
from rfsas_hw.ros2.scene import BEARING_ARRAY_SPAN_NS, SceneBuilder, SceneConfig
from rfsas_hw.ros2.sink import BackendScene, SceneSink

BATCH_GAP_NS = BEARING_ARRAY_SPAN_NS
"""Bearings of one sensor closer than this to the batch's first become one array, ns."""


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


def _pose(line: BearingLine, poses: Mapping[str, Pose]) -> Pose | None:
    """The sensor's pose: the one given by id, else the line's own (heading 0 if unknown)."""
    pose = poses.get(line.sensor_id)
    if pose is None and math.isfinite(line.x_m) and math.isfinite(line.y_m):
        heading = line.heading_deg if math.isfinite(line.heading_deg) else 0.0
        pose = Pose(line.x_m, line.y_m, heading)
    return pose


def _batch(rows: list[BearingLine]) -> BearingBatch:
    return BearingBatch(
        sensor_id=rows[0].sensor_id,
        t_ns=np.array([r.t_ns for r in rows], np.int64),
        azimuth_deg=np.array([r.azimuth_deg for r in rows]),
        sigma_deg=np.array([r.sigma_deg for r in rows]),
        snr_db=np.array([r.snr_db for r in rows]),
        channel=np.array([r.channel for r in rows], np.int16),
        emitter=np.array([int(r.emitter, 16) for r in rows], np.uint64),
        relative_deg=np.array([r.relative_deg for r in rows]),
    )


def read_events(
    path: str | Path, poses: Mapping[str, Pose], result: ExportResult
) -> Iterator[tuple[int, Any]]:
    """The bearing batches and backend steps of one JSONL file, in file order.

    Raises:
        DataFormatError: the file cannot be read.
    """
    pending: list[BearingLine] = []
    pending_pose: Pose | None = None
    step: _Step | None = None

    def flush_bearings() -> Iterator[tuple[int, Any]]:
        if pending:
            batch = _batch(pending)
            yield int(batch.t_ns.max()), (batch, pending_pose)
            pending.clear()

    records = iter_records(path, result.skipped, result.errors, default_record="bearing")
    for record in records:
        if isinstance(record, BearingLine):
            pose = _pose(record, poses)
            if pending and (
                record.sensor_id != pending[0].sensor_id
                or pose != pending_pose
                or abs(record.t_ns - pending[0].t_ns) > BATCH_GAP_NS
            ):
                yield from flush_bearings()
            if not pending:
                pending_pose = pose
            pending.append(record)
        elif isinstance(record, Fix):
            if step is not None and step.assessments:
                yield step.t_ns, step
                step = None
            if step is None:
                step = _Step(record.t_ns)
            step.fixes.append(record)
            step.t_ns = max(step.t_ns, record.t_ns)
        elif isinstance(record, Assessment):
            if step is not None and step.assessments and step.assessments[0].t_ns != record.t_ns:
                yield step.t_ns, step
                step = None
            if step is None:
                step = _Step(record.t_ns)
            step.assessments.append(record)
            step.t_ns = record.t_ns
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
        OutputError: a temporary file of the time sort cannot be written.
    """
    poses = dict(poses or {})
    target = Path(out).resolve()
    for path in runs:
        if Path(path).resolve() == target:
            raise ConfigError(f"{out} is also an input; refusing to write over it")
    result = ExportResult()
    with ExternalSort() as events:
        for path in runs:
            for t_ns, item in read_events(path, poses, result):
                events.add((t_ns,), pickle.dumps(item, protocol=pickle.HIGHEST_PROTOCOL))
        _record(events, out, fmt, storage, scene, result)
    return result


def _record(
    events: ExternalSort,
    out: str | Path,
    fmt: RecordFormat,
    storage: str,
    scene: SceneConfig | None,
    result: ExportResult,
) -> None:
    """Write the sorted events through the live run's scene into the recording."""
    sink = SceneSink([open_recording(out, fmt, storage=storage)], SceneBuilder(scene))
    stations: dict[str, Pose] = {}
    backend = BackendScene(sink, stations=lambda: stations)
    try:
        for data in events.sorted():
            item = pickle.loads(data)  # our own events from our own file
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
