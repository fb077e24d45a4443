"""A recorded backend run as CPMs in a pcap of GeoNetworking + BTP-B frames.

``rfsas export run.jsonl --to cpm`` replays the run log's assessments step by step
(one step per distinct assessment time) through a :class:`CpmGenerator`, as the
live sink would have, with the units' poses from the log's bearing lines, and
writes each message as an Ethernet frame (type 0x8947) stamped with its step's
time. Wireshark and tshark read the GeoNetworking, BTP-B and ITS PDU header layers
(a build with the CPM v2 dissector reads the body too).
"""

from __future__ import annotations

import io
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, cast

from rfsas_hw.errors import ExportError
from rfsas_hw.exports.run import RunLog, read_run
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


def export_cpm_pcap(
    run_path: str | Path,
    out: str | Path,
    *,
    station_id: int = 1,
    origin: SiteOrigin | None = None,
) -> CpmExport:
    """Write the run log's tracks as CPM frames to the pcap ``out``.

    Args:
        run_path: a backend run log (``rfsas backend --out run.jsonl``).
        out: the pcap to write (replaced only once complete).
        station_id: the roadside station's ``StationId``.
        origin: the site origin (default: the log's ``site`` line).

    Raises:
        ExportError: unreadable log, no origin, or the file cannot be written.
        MissingDependencyError: ``asn1tools`` is not installed (the ``v2x`` extra).
    """
    run = read_run(run_path)
    where = run.origin_or(origin)
    steps: dict[int, list[Assessment]] = defaultdict(list)
    for a in run.assessments:
        steps[a.t_ns].append(a)
    bearings = sorted(run.bearings, key=lambda b: b.t_ns)
    generator = CpmGenerator(CpmConfig(station_id=station_id, origin=where))
    stations: dict[str, Pose] = {}
    position = GeoPosition(where.lat_deg, where.lon_deg)
    frames: list[tuple[int, bytes]] = []
    objects = 0
    k = 0
    for t_ns in sorted(steps):
        while k < len(bearings) and bearings[k].t_ns <= t_ns:
            b = bearings[k]
            if b.x_m == b.x_m and b.y_m == b.y_m:  # a bearings file line has no pose
                stations[b.sensor_id] = Pose(b.x_m, b.y_m, b.heading_deg)
            k += 1
        for message in generator.step(t_ns, steps[t_ns], stations):
            frames.append(
                (t_ns, ethernet_frame(message.data, station_id, STATION_TYPE_RSU, t_ns, position))
            )
            objects += len(message.cpm.objects)
    path = Path(out)
    try:
        with AtomicFile(path) as f:
            # the atomic file is a text stream over a binary one: the pcap goes to the latter
            write_pcap(cast(BinaryIO, cast(io.TextIOWrapper, f.stream).buffer), frames)
    except OSError as err:
        raise ExportError(f"{path}: cannot write: {err.strerror or err}") from err
    return CpmExport(path, len(frames), objects, len(steps), run)
