"""DDS: the bytes Cyclone DDS publishes are rosbags' CDR (as samples and as captured on the
wire), and a loopback round trip to another process delivers every message of a short run.

Cyclone DDS is confined to the loopback interface (``lo``, multicast off,
unicast discovery to 127.0.0.1) on a domain id picked from the process id,
so concurrent test runs on one machine do not meet and nothing leaves the host.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("cyclonedds", reason="needs the ros2 extra: pip install 'rfsas-hw[ros2]'")

from rosrun import read_mcap, run_backend
from rtps import user_samples

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
DOMAIN = 100 + os.getpid() % 40
"""Domains 100–140 here; the leak test uses 149–199 and the CLI tests 211–212."""


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


@dataclass
class RoundTrip:
    recorded: list[tuple[str, bytes]]
    """(topic, CDR) of every message of the reference recording."""
    received: list[tuple[str, bytes]]
    """(topic, re-serialised sample) of every message the other process took."""
    done_line: str
    expected: int
    wire: Path | None
    """A pcap of the domain's UDP ports during the run (None: capture not permitted)."""
    stderr: str


def start_capture(path: Path) -> subprocess.Popen[bytes] | None:
    """dumpcap on lo, this test's domain's RTPS ports only; None where capturing is not
    permitted or dumpcap is missing."""
    if shutil.which("dumpcap") is None:
        return None
    base = 7400 + 250 * DOMAIN  # RTPS port mapping: PB + DG · domain, 250 ports per domain
    cmd = ["dumpcap", "-q", "-P", "-i", "lo", "-f", f"udp portrange {base}-{base + 249}"]
    cap = subprocess.Popen([*cmd, "-w", str(path)], stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 5
    while not path.exists() and cap.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    if cap.poll() is not None or not path.exists():
        cap.kill()
        cap.wait()
        return None
    return cap


@pytest.fixture(scope="module")
def round_trip(tmp_path_factory: pytest.TempPathFactory) -> RoundTrip:
    """The short run published on loopback DDS to a subscriber in another process."""
    tmp = tmp_path_factory.mktemp("dds")
    (tmp / "a").mkdir()
    ref = run_backend(tmp / "a", [McapFileWriter(tmp / "a" / "ref.mcap")])
    expected = sum(ref.sink.counts.values())
    wire = tmp / "wire.pcap"
    cap = start_capture(wire)
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
        (tmp / "b").mkdir()
        run_backend(tmp / "b", [AckedPublisher(publisher)])
        out, err = proc.communicate(timeout=60)
    finally:
        if publisher is not None:
            publisher.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        if cap is not None:
            time.sleep(0.3)  # let dumpcap write the last packets
            cap.terminate()
            cap.wait(timeout=10)
    lines = out.splitlines()
    return RoundTrip(
        recorded=[(m.topic, m.data) for m in read_mcap(tmp / "a" / "ref.mcap")],
        received=[(d["topic"], bytes.fromhex(d["cdr"])) for d in map(json.loads, lines[:-1])],
        done_line=lines[-1] if lines else "",
        expected=expected,
        wire=wire if cap is not None else None,
        stderr=err,
    )


def test_loopback_round_trip_delivers_every_message(round_trip: RoundTrip) -> None:
    assert round_trip.done_line == f"done {round_trip.expected}", round_trip.stderr[-2000:]
    assert sorted(round_trip.received) == sorted(round_trip.recorded)


def test_rtps_payloads_on_the_wire_are_rosbags_cdr(round_trip: RoundTrip) -> None:
    """The serialized payload of every user DATA submessage captured on lo is the rosbags
    CDR of a recorded message, followed only by the zero padding that aligns the next
    RTPS submessage to 4 bytes."""
    if round_trip.wire is None:
        pytest.skip("capturing on lo is not permitted here (dumpcap missing or not privileged)")
    samples = user_samples(round_trip.wire)
    assert len(samples) == round_trip.expected
    padded = sorted(data + bytes(-len(data) % 4) for _, data in round_trip.recorded)
    assert sorted(samples.values()) == padded
    # CDR little-endian, plain (XCDR1) encapsulation, as rosbags writes it
    assert {payload[:4] for payload in samples.values()} == {b"\x00\x01\x00\x00"}


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


def test_odometry_feed_skips_instance_state_notices() -> None:
    """When a publisher leaves, Cyclone DDS hands the reader an InvalidSample (no data):
    the feed skips it instead of failing, and keeps the last vehicle state."""
    from cyclonedds.internal import InvalidSample

    from rfsas_hw.backend.vehicle import VehicleState

    state = VehicleState(x_m=1.0, y_m=2.0, heading_deg=90.0, speed_mps=5.0, t_ns=1_000_000_000)
    (odom,) = [o for o in SceneBuilder().vehicle(state.t_ns, state) if o.topic is topics.EGO]

    class Reader:
        def __init__(self, batches: list[list[Any]]) -> None:
            self.batches = batches

        def take(self, N: int = 1) -> list[Any]:
            return self.batches.pop(0) if self.batches else []

    feed = OdometryFeed("/odom", DdsConfig(domain_id=DOMAIN + 2, interface="lo"))
    try:
        notice = InvalidSample(key_sample=None, sample_info=None)  # type: ignore[arg-type]
        feed._reader = Reader([[odom.message, notice], [notice]])
        first = feed.poll()
        second = feed.poll()
    finally:
        feed.close()
    assert first is not None and second is first
    assert feed.received == 1 and feed.rejected == 0
