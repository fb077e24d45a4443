"""A recorded backend run as CPMs in a pcap of GeoNetworking + BTP-B frames.

``rfsas export run.jsonl --to cpm`` replays the run log's assessments step by step
(one step per distinct assessment time) through a :class:`CpmGenerator`, as the
live sink would have, with the units' poses from the log's bearing lines, and
writes each message as an Ethernet frame (type 0x8947) stamped with its step's
time. Wireshark and tshark read the GeoNetworking, BTP-B and ITS PDU header layers
(a build with the CPM v2 dissector reads the body too). The log is read record by
record and the frames are written as they are made: memory holds the time sort's
budget, not the log.
"""

from __future__ import annotations

import pickle
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, cast

from rfsas_hw.errors import ExportError
from rfsas_hw.exports.run import BearingLine, RunLog
from rfsas_hw.exports.spill import ExternalSort
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.outpaths import AtomicFile
from rfsas_hw.records import Assessment, Pose
from rfsas_hw.v2x.geonet import GeoPosition, ethernet_frame, write_pcap
from rfsas_hw.v2x.perception import CpmConfig, CpmGenerator

__all__ = ["STATION_TYPE_RSU", "CpmExport", "export_cpm_pcap"]

STATION_TYPE_RSU = 15
"""``StationType`` roadSideUnit, in the GeoNetworking address."""


@dataclass(frozen=True, slots=True)
class CpmExport:
    """What an export wrote."""

    path: Path
    """The pcap file."""
    messages: int
    """CPMs (frames) written."""
    objects: int
    """Perceived objects over all messages."""
    steps: int
    """Backend steps replayed."""
    run: RunLog
    """The log read (its skip counters)."""


def _steps(run: RunLog) -> Iterator[tuple[int, list[Assessment], dict[str, Pose]]]:
    """The run's backend steps in time order: (time, its assessments, the units' poses
    from the bearings up to that time).

    A step is one distinct assessment time; the records are put in time order by
    an :class:`~rfsas_hw.exports.spill.ExternalSort` (a bearing before a step at
    its own time), so a long log is replayed in bounded memory.
    """
    stations: dict[str, Pose] = {}
    with ExternalSort() as events:
        for r in run.records():
            if isinstance(r, Assessment):
                events.add((r.t_ns, 1), pickle.dumps(r, protocol=pickle.HIGHEST_PROTOCOL))
            elif isinstance(r, BearingLine) and r.x_m == r.x_m and r.y_m == r.y_m:
                # a bearings file line has no pose: it places no unit
                pose = (r.sensor_id, r.x_m, r.y_m, r.heading_deg)
                events.add((r.t_ns, 0), pickle.dumps(pose, protocol=pickle.HIGHEST_PROTOCOL))
        step: list[Assessment] = []
        for data in events.sorted():
            item = pickle.loads(data)  # our own records from our own file
            if isinstance(item, Assessment):
                if step and step[0].t_ns != item.t_ns:
                    yield step[0].t_ns, step, stations
                    step = []
                step.append(item)
                continue
            if step:  # a later bearing: the step is complete
                yield step[0].t_ns, step, stations
                step = []
            sensor_id, x_m, y_m, heading_deg = item
            stations[sensor_id] = Pose(x_m, y_m, heading_deg)
        if step:
            yield step[0].t_ns, step, stations


def export_cpm_pcap(
    run_path: str | Path,
    out: str | Path,
    *,
    station_id: int = 1,
    origin: SiteOrigin | None = None,
) -> CpmExport:
    """Write the run log's tracks as CPM frames to the pcap ``out``, as the log is read.

    Args:
        run_path: a backend run log (``rfsas backend --out run.jsonl``).
        out: the pcap to write (replaced only once complete).
        station_id: the roadside station's ``StationId``.
        origin: the site origin (default: the log's ``site`` line).

    Raises:
        ExportError: unreadable log, no origin, or the file cannot be written.
        OutputError: a temporary file of the time sort cannot be written.
        MissingDependencyError: ``asn1tools`` is not installed (the ``v2x`` extra).
    """
    run = RunLog(source=str(Path(run_path)))
    where = run.origin_or(origin)
    generator = CpmGenerator(CpmConfig(station_id=station_id, origin=where))
    position = GeoPosition(where.lat_deg, where.lon_deg)
    counts = {"objects": 0, "steps": 0}

    def frames() -> Iterator[tuple[int, bytes]]:
        for t_ns, assessments, stations in _steps(run):
            counts["steps"] += 1
            for message in generator.step(t_ns, assessments, stations):
                counts["objects"] += len(message.cpm.objects)
                yield (
                    t_ns,
                    ethernet_frame(message.data, station_id, STATION_TYPE_RSU, t_ns, position),
                )

    path = Path(out)
    try:
        with AtomicFile(path, binary=True) as f:
            messages = write_pcap(cast(BinaryIO, f.stream), frames())
    except OSError as err:
        raise ExportError(f"{path}: cannot write: {err.strerror or err}") from err
    return CpmExport(path, messages, counts["objects"], counts["steps"], run)
