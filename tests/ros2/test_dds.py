"""DDS: the bytes Cyclone DDS publishes are rosbags' CDR, and a loopback round trip
to another process delivers every message of a short run.

Cyclone DDS is confined to the loopback interface (``lo``, multicast off,
unicast discovery to 127.0.0.1) on a domain id picked from the process id,
so concurrent test runs on one machine do not meet and nothing leaves the host.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("cyclonedds")

from rosrun import read_mcap, run_backend

from rfsas_hw.ros2 import topics
from rfsas_hw.ros2.bag import McapFileWriter
from rfsas_hw.ros2.dds import (
    DdsConfig,
    DdsPublisher,
    OdometryFeed,
    idl_class,
    odometry_to_vehicle,
)
from rfsas_hw.ros2.scene import SceneBuilder
from rfsas_hw.ros2.topics import Topic
from rfsas_hw.ros2.types import serialize

HERE = Path(__file__).resolve().parent
DOMAIN = 100 + os.getpid() % 100


def test_dds_samples_serialise_to_the_bag_bytes(tmp_path: Path) -> None:
    """Every message of a run, as the Cyclone DDS sample the publisher writes, serialises
    to exactly the CDR bytes rosbags wrote into the recording."""
    run_backend(tmp_path, [McapFileWriter(tmp_path / "run.mcap")])
    msgs = read_mcap(tmp_path / "run.mcap")
    assert {m.typename for m in msgs} == {t.typename for t in topics.ALL}
    for m in msgs:
        sample = idl_class(m.typename).deserialize(m.data)
        assert sample.serialize() == m.data, m.topic
    # and the names ROS 2 uses on the wire
    assert topics.BEARINGS.dds_name == "rt/rfsas/bearings"
    assert idl_class("rfsas_msgs/msg/BearingArray").__idl_typename__ == (
        "rfsas_msgs::msg::dds_::BearingArray_"
    )


class AckedPublisher:
    """Publish, then wait (bounded) until the reader acknowledged: KEEP_LAST never drops."""

    def __init__(self, publisher: DdsPublisher) -> None:
        self.publisher = publisher
        self.unacked: dict[str, int] = {}

    def write(self, topic: Topic, log_time_ns: int, data: bytes) -> None:
        self.publisher.write(topic, log_time_ns, data)
        self.unacked[topic.name] = self.unacked.get(topic.name, 0) + 1
        if self.unacked[topic.name] >= topic.depth - 1:
            # a KEEP_LAST writer may drop a sample only once `depth` are unacknowledged
            assert self.publisher.wait_for_acks(5.0), topic.name
            self.unacked.clear()

    def close(self) -> None:
        self.publisher.close()


def test_loopback_round_trip_delivers_every_message(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    ref = run_backend(tmp_path / "a", [McapFileWriter(tmp_path / "a" / "ref.mcap")])
    expected = sum(ref.sink.counts.values())
    env = {k: v for k, v in os.environ.items() if not k.startswith("CYCLONEDDS")}
    proc = subprocess.Popen(
        [sys.executable, str(HERE / "dds_listen.py"), str(DOMAIN), str(expected), "40"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=HERE,
    )
    publisher = None
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "ready", proc.stderr.read() if proc.stderr else ""
        publisher = DdsPublisher(DdsConfig(domain_id=DOMAIN, interface="lo"))
        deadline = time.monotonic() + 20
        while not all(publisher.matched(t) for t in topics.ALL):
            assert time.monotonic() < deadline, "the listener was never discovered"
            time.sleep(0.05)
        (tmp_path / "b").mkdir()
        run_backend(tmp_path / "b", [AckedPublisher(publisher)])
        out, err = proc.communicate(timeout=60)
    finally:
        if publisher is not None:
            publisher.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    lines = out.splitlines()
    assert lines[-1] == f"done {expected}", err[-2000:]
    received = sorted((d["topic"], bytes.fromhex(d["cdr"])) for d in map(json.loads, lines[:-1]))
    recorded = sorted((m.topic, m.data) for m in read_mcap(tmp_path / "a" / "ref.mcap"))
    assert received == recorded


def test_odometry_feed_gives_the_vehicle_state() -> None:
    """A nav_msgs/Odometry published on /odom (loopback) becomes the backend's vehicle state:
    ENU yaw → compass heading, body-frame speed, header stamp."""
    from rfsas_hw.backend.vehicle import VehicleState

    config = DdsConfig(domain_id=DOMAIN + 1, interface="lo")
    state = VehicleState(
        x_m=3.0, y_m=-40.0, heading_deg=20.0, speed_mps=9.5, t_ns=1_763_800_000_500_000_000
    )
    (odom,) = [o for o in SceneBuilder().vehicle(state.t_ns, state) if o.topic is topics.EGO]
    data = serialize(odom.message, topics.EGO.typename)
    want = odometry_to_vehicle(odom.message)
    assert (want.x_m, want.y_m, want.speed_mps, want.t_ns) == (3.0, -40.0, 9.5, state.t_ns)
    assert want.heading_deg == pytest.approx(20.0)

    feed = OdometryFeed("/odom", config)
    publisher = DdsPublisher(config)
    odom_topic = Topic("/odom", "nav_msgs/msg/Odometry", "test odometry")
    try:
        deadline = time.monotonic() + 20
        while not publisher.matched(odom_topic):
            assert time.monotonic() < deadline
            time.sleep(0.05)
        publisher.write(odom_topic, state.t_ns, data)
        got: Any = None
        while got is None and time.monotonic() < deadline:
            got = feed.poll()
            time.sleep(0.02)
    finally:
        publisher.close()
        feed.close()
    assert got is not None and feed.received == 1
    assert (got.x_m, got.y_m, got.t_ns) == (3.0, -40.0, state.t_ns)
    assert got.heading_deg == pytest.approx(20.0) and got.speed_mps == pytest.approx(9.5)
