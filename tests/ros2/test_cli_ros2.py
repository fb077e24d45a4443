"""The ROS 2 options of the commands: ``rfsas backend --out run.mcap --rosbag2 DIR
--foxglove 0 --ros2`` on real UDP with real keys, and ``rfsas replay --out run.mcap``."""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

pytest.importorskip("rosbags", reason="needs the ros2 extra: pip install 'rfsas-hw[ros2]'")
pytest.importorskip("foxglove", reason="needs the ros2 extra: pip install 'rfsas-hw[ros2]'")
pytest.importorskip("cyclonedds", reason="needs the ros2 extra: pip install 'rfsas-hw[ros2]'")

from rosrun import read_mcap, read_rosbag2_sqlite

from rfsas_hw.angles import math_rad_to_compass
from rfsas_hw.cli.backend import backend
from rfsas_hw.link import Publisher
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.records import BearingBatch, Pose
from rfsas_hw.ros2 import topics

EMITTER = 0xC0FF_EE00_0000_0042
TARGET = np.array([-6.0, 22.0])
SENSORS = {"rsu-n": Pose(-35.0, 10.0, 90.0), "rsu-s": Pose(25.0, -5.0, 0.0)}


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def send_rounds(url: str, stores: dict[str, KeyStore], rounds: int = 20) -> None:
    time.sleep(0.3)
    pubs = {sid: Publisher.to_url(url, stores[sid].signer(), pose) for sid, pose in SENSORS.items()}
    try:
        for _ in range(rounds):
            now = time.time_ns()
            for sid, pose in SENSORS.items():
                d = TARGET - np.array([pose.x_m, pose.y_m])
                az = float(math_rad_to_compass(np.arctan2(d[1], d[0])))
                one = BearingBatch(
                    sid,
                    np.array([now], np.int64),
                    np.array([az]),
                    np.array([1.0]),
                    np.array([20.0]),
                    np.array([11], np.int16),
                    np.array([EMITTER], np.uint64),
                )
                pubs[sid].on_bearings(one)
            time.sleep(0.1)
    finally:
        for pub in pubs.values():
            pub.close()


def free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def foxglove_client(port: int, frames: list[tuple[str, bytes]], stop: threading.Event) -> None:
    """Connect (retrying while the command starts), subscribe to every channel, collect
    (topic, payload) of every message frame until the server goes away or ``stop``."""
    import json
    import struct

    import websocket

    deadline = time.monotonic() + 10
    while True:
        # probe with a plain socket: a refused websocket attempt leaves its socket unclosed
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                break
        except OSError:
            if time.monotonic() > deadline or stop.is_set():
                return
            time.sleep(0.05)
    ws = websocket.create_connection(
        f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"], timeout=2
    )
    try:
        channels: dict[int, str] = {}
        while len(channels) < len(topics.ALL):
            msg = json.loads(ws.recv())
            if msg["op"] == "advertise":
                channels.update({c["id"]: c["topic"] for c in msg["channels"]})
        subs = [{"id": cid, "channelId": cid} for cid in channels]
        ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
        ws.settimeout(0.2)
        while not stop.is_set():
            try:
                opcode, data = ws.recv_data()
            except websocket.WebSocketTimeoutException:
                continue
            except (websocket.WebSocketConnectionClosedException, OSError):
                return
            if opcode == websocket.ABNF.OPCODE_BINARY and data and data[0] == 1:
                sub = struct.unpack_from("<I", data, 1)[0]
                frames.append((channels[sub], bytes(data[13:])))
    finally:
        ws.close()
        # close() leaves the socket open once the server's close frame has been read
        ws.shutdown()


def test_backend_records_mcap_and_rosbag2_and_serves_foxglove(tmp_path: Path) -> None:
    """Recorded twice and served live: a Foxglove client connected while the command runs
    receives the scene the recordings hold."""
    pytest.importorskip("websocket", reason="needs the dev extra: pip install 'rfsas-hw[dev]'")
    backend_keys = KeyStore.create(tmp_path / "backend", "backend", "obu-1")
    stores = {sid: KeyStore.create(tmp_path / sid, "sensor", sid) for sid in SENSORS}
    for store in stores.values():
        backend_keys.trust.enroll(store.card)
    vehicle = tmp_path / "vehicle.json"
    vehicle.write_text('{"x_m": -12, "y_m": 22, "heading_deg": 90, "speed_mps": 8}')
    url = f"udp://127.0.0.1:{free_port()}"
    sender = threading.Thread(target=send_rounds, args=(url, stores))
    sender.start()
    port = free_tcp_port()
    frames: list[tuple[str, bytes]] = []
    stop = threading.Event()
    client = threading.Thread(target=foxglove_client, args=(port, frames, stop))
    client.start()
    mcap, bag = tmp_path / "run.mcap", tmp_path / "run_bag"
    try:
        result = CliRunner().invoke(
            backend,
            [
                "--listen", url, "--keys", str(tmp_path / "backend"), "--vehicle", str(vehicle),
                "--out", str(mcap), "--rosbag2", str(bag), "--foxglove", str(port),
                "--ros2", "--ros2-interface", "lo", "--ros2-domain", "211",
                "--duration", "2.5", "--no-table",
            ],
        )  # fmt: skip
    finally:
        stop.set()
        sender.join()
        client.join(timeout=10)
    assert result.exit_code == 0, result.output
    assert f"foxglove: open ws://127.0.0.1:{port}" in result.output
    assert "ros2: publishing on domain 211" in result.output
    msgs = read_mcap(mcap)
    assert [m.data for m in msgs] == [m.data for m in read_rosbag2_sqlite(bag)]
    # the live client saw the same scene: every frame is a recorded message, and the
    # frames cover the scene's topics
    recorded = {(m.topic, m.data) for m in msgs}
    assert frames and all(frame in recorded for frame in frames)
    assert {topics.MARKERS.name, topics.TF.name, topics.ASSESSMENTS.name} <= {t for t, _ in frames}
    fixes = [f for m in msgs if m.topic == topics.FIXES.name for f in m.message.fixes]
    assert fixes and all(f.emitter_id == f"{EMITTER:016x}" for f in fixes)
    ok = [f for f in fixes if f.ok]
    assert ok and abs(ok[0].position.x - TARGET[0]) < 1e-3
    assessed = [
        a for m in msgs if m.topic == topics.ASSESSMENTS.name for a in m.message.assessments
    ]
    # the pedestrian is ahead of the car: brake (caution if the loaded machine delays the link)
    assert assessed and all(a.advisory in (2, 3) for a in assessed)
    bearings = [b for m in msgs if m.topic == topics.BEARINGS.name for b in m.message.bearings]
    assert {b.sensor_id for b in bearings} == set(SENSORS)
    frames = {
        t.child_frame_id for m in msgs if m.topic == topics.TF.name for t in m.message.transforms
    }
    assert frames == {"rfsas/sensor/rsu-n", "rfsas/sensor/rsu-s", "rfsas/ego"}
    link = [m.message for m in msgs if m.topic == topics.LINK.name]
    assert link and link[-1].verified > 0


def test_backend_takes_the_vehicle_from_ros2_odometry(tmp_path: Path) -> None:
    """``--odom /odom``: the vehicle state comes from nav_msgs/Odometry on loopback DDS."""
    from rfsas_hw.backend.vehicle import VehicleState
    from rfsas_hw.ros2.dds import DdsConfig, DdsPublisher
    from rfsas_hw.ros2.scene import SceneBuilder
    from rfsas_hw.ros2.topics import Topic
    from rfsas_hw.ros2.types import serialize

    domain = 212
    backend_keys = KeyStore.create(tmp_path / "backend", "backend", "obu-1")
    stores = {sid: KeyStore.create(tmp_path / sid, "sensor", sid) for sid in SENSORS}
    for store in stores.values():
        backend_keys.trust.enroll(store.card)
    url = f"udp://127.0.0.1:{free_port()}"
    odom_topic = Topic("/odom", "nav_msgs/msg/Odometry", "test odometry")
    publisher = DdsPublisher(DdsConfig(domain_id=domain, interface="lo"))
    stop = threading.Event()

    def send_odometry() -> None:
        while not stop.is_set():
            now = time.time_ns()
            state = VehicleState(x_m=-12.0, y_m=22.0, heading_deg=90.0, speed_mps=8.0, t_ns=now)
            (odom,) = [o for o in SceneBuilder().vehicle(now, state) if o.topic is topics.EGO]
            publisher.write(odom_topic, now, serialize(odom.message, odom_topic.typename))
            time.sleep(0.05)

    sender = threading.Thread(target=send_rounds, args=(url, stores))
    odometry = threading.Thread(target=send_odometry)
    sender.start()
    odometry.start()
    mcap = tmp_path / "run.mcap"
    try:
        result = CliRunner().invoke(
            backend,
            [
                "--listen", url, "--keys", str(tmp_path / "backend"), "--out", str(mcap),
                "--odom", "/odom", "--ros2-interface", "lo", "--ros2-domain", str(domain),
                "--duration", "2.5", "--no-table",
            ],
        )  # fmt: skip
    finally:
        stop.set()
        sender.join()
        odometry.join()
        publisher.close()
    assert result.exit_code == 0, result.output
    assert "ros2: vehicle state from /odom" in result.output
    msgs = read_mcap(mcap)
    ego = [m.message for m in msgs if m.topic == topics.EGO.name]
    assert ego, "the backend never had a vehicle state"
    assert ego[0].pose.pose.position.y == pytest.approx(22.0)
    assessed = [
        a for m in msgs if m.topic == topics.ASSESSMENTS.name for a in m.message.assessments
    ]
    assert any(a.advisory in (2, 3) and a.p_collision > 0.2 for a in assessed)
