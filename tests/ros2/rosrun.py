"""A short backend run for the ROS 2 tests, and readers that decode recordings without rfsas.

The run: two roadside sensors, a pedestrian crossing in front of a car and a
parked phone, three seconds of noisy bearings at 10 Hz through the real
backend service. Its sinks are the JSONL run log and the ROS 2 scene, so the
test compares a recording with the JSONL of the same run.

The readers use ``mcap`` with ``mcap-ros2-support``'s CDR decoder, and the
standard library's ``sqlite3`` for rosbag2: nothing of the writer
(``rosbags``' serialiser) is involved in reading back.
"""

from __future__ import annotations

import glob
import json
import math
import sqlite3
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rfsas_hw.backend.service import BackendConfig, BackendService, JsonlSink
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.records import BearingBatch, Pose
from rfsas_hw.ros2.bag import MessageWriter
from rfsas_hw.ros2.sink import BackendScene, SceneSink

NS = 1_000_000_000
T0_NS = 1_763_800_000 * NS
SENSORS = {"rsu-1": Pose(-20.0, -12.0, 30.0), "rsu-2": Pose(22.0, -10.0, 320.0)}
EMITTERS = {0x5A1D_33C0_FFEE_0001: "walker", 0x0B0E_77A1_2222_0002: "parked"}
STEPS = 30
STEP_NS = NS // 10


def emitter_xy(kind: str, t_s: float) -> tuple[float, float]:
    if kind == "walker":
        return (-6.0 + 1.4 * t_s, 8.0)
    return (12.0, 18.0)


def compass_from(pose: Pose, xy: tuple[float, float]) -> float:
    return math.degrees(math.atan2(xy[0] - pose.x_m, xy[1] - pose.y_m)) % 360.0


@dataclass
class ShortRun:
    jsonl: Path
    service: BackendService
    vehicle: VehicleState
    sink: SceneSink
    batches: list[BearingBatch] = field(default_factory=list)


def run_backend(tmp: Path, writers: list[MessageWriter], seed: int = 7) -> ShortRun:
    """Run the scenario through the backend with the JSONL sink and a scene of ``writers``."""
    rng = np.random.default_rng(seed)
    jsonl = tmp / "run.jsonl"
    service = BackendService(BackendConfig(), clock=lambda: T0_NS, link_alarm=lambda: False)
    service.link_stats = lambda: {"verified": 60, "datagrams": 61, "rejected.stale": 1}
    service.sinks.append(JsonlSink(jsonl, bearings=True))
    sink = SceneSink(writers)
    service.sinks.append(BackendScene.for_service(sink, service))
    vehicle = VehicleState(x_m=-2.0, y_m=-40.0, heading_deg=0.0, speed_mps=8.0, t_ns=T0_NS)
    service.set_vehicle(vehicle)
    run = ShortRun(jsonl, service, vehicle, sink)
    for k in range(1, STEPS + 1):
        t_end = T0_NS + k * STEP_NS
        for sensor_id, pose in SENSORS.items():
            t = np.sort(rng.integers(t_end - STEP_NS, t_end, size=2 * len(EMITTERS)))
            ids = np.repeat(np.array(list(EMITTERS), np.uint64), 2)
            az = np.array(
                [
                    compass_from(pose, emitter_xy(EMITTERS[int(e)], (ti - T0_NS) / NS))
                    for e, ti in zip(ids.tolist(), t.tolist(), strict=True)
                ]
            )
            az = (az + rng.normal(0.0, 1.5, len(az))) % 360.0
            batch = BearingBatch(
                sensor_id,
                t,
                az,
                np.full(len(az), 1.5),
                rng.uniform(12.0, 30.0, len(az)),
                np.full(len(az), 6, np.int16),
                ids,
                relative_deg=(az - pose.heading_deg + 180.0) % 360.0 - 180.0,
            )
            run.batches.append(batch)
            service.on_bearings(batch, pose)
        service.step(now_ns=t_end)
    service.close()
    return run


def jsonl_records(path: Path) -> dict[str, list[dict[str, Any]]]:
    out: dict[str, list[dict[str, Any]]] = {"bearing": [], "fix": [], "assessment": []}
    for line in path.read_text().splitlines():
        data = json.loads(line)
        if data["record"] in out:
            out[data["record"]].append(data)
    return out


@dataclass
class Decoded:
    topic: str
    typename: str
    log_time_ns: int
    message: Any
    data: bytes


def read_mcap(path: Path) -> list[Decoded]:
    """Every message of an MCAP file, decoded by mcap-ros2-support."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out = []
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            assert schema is not None
            out.append(
                Decoded(channel.topic, schema.name, message.log_time, decoded, bytes(message.data))
            )
    return out


def read_rosbag2_sqlite(path: Path) -> list[Decoded]:
    """Every message of a sqlite3 rosbag2 directory: plain SQL, schemas from the bag's own
    ``message_definitions`` table, CDR decoded by mcap-ros2-support."""
    from mcap_ros2._dynamic import generate_dynamic

    (db,) = glob.glob(str(path / "*.db3"))
    con = sqlite3.connect(db)
    try:
        defs = dict(
            con.execute("SELECT topic_type, encoded_message_definition FROM message_definitions")
        )
        topics = {
            tid: (name, typ, fmt)
            for tid, name, typ, fmt in con.execute(
                "SELECT id, name, type, serialization_format FROM topics"
            )
        }
        decoders = {}
        for name, typ, fmt in topics.values():
            assert fmt == "cdr", (name, fmt)
            decoders[typ] = generate_dynamic(typ, defs[typ])[typ]
        out = []
        for tid, ts, data in con.execute(
            "SELECT topic_id, timestamp, data FROM messages ORDER BY timestamp, id"
        ):
            name, typ, _ = topics[tid]
            out.append(Decoded(name, typ, int(ts), decoders[typ](bytes(data)), bytes(data)))
        return out
    finally:
        con.close()
