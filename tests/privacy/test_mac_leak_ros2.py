"""No raw MAC in any ROS 2 output: MCAP files, rosbag2 directories, Foxglove frames, DDS samples.

Frames from known MACs go through the real sensor pipeline; everything each
ROS 2 output holds or sends is captured and searched with the leak search of
``test_mac_leak`` (hex in any separator and case, raw bytes either way,
decimal, base64). MCAP chunks are compressed, so besides the file's bytes
the test searches every decompressed message, schema and channel record too.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags", reason="needs the ros2 extra: pip install 'rfsas-hw[ros2]'")
pytest.importorskip("mcap", reason="needs the ros2 extra: pip install 'rfsas-hw[ros2]'")
pytest.importorskip("foxglove", reason="needs the ros2 extra: pip install 'rfsas-hw[ros2]'")
pytest.importorskip("cyclonedds", reason="needs the ros2 extra: pip install 'rfsas-hw[ros2]'")
websocket = pytest.importorskip(
    "websocket", reason="needs the dev extra: pip install 'rfsas-hw[dev]'"
)

from privhelp import (  # noqa: E402
    CALIBRATION,
    KNOWN_MACS,
    STILL,
    known_frames,
    write_known_capture,
)
from test_mac_leak import find_leaks  # noqa: E402

from rfsas_hw.df import load_calibration  # noqa: E402
from rfsas_hw.pipeline import SensorPipeline  # noqa: E402
from rfsas_hw.privacy import FixedNonce, MacHasher  # noqa: E402
from rfsas_hw.records import Pose  # noqa: E402
from rfsas_hw.ros2 import topics  # noqa: E402
from rfsas_hw.ros2.dds import DdsConfig, DdsPublisher, idl_class, qos_of  # noqa: E402
from rfsas_hw.ros2.foxglove_live import FoxgloveServer  # noqa: E402
from rfsas_hw.ros2.sink import SceneSink, SensorScene  # noqa: E402


def mcap_blobs(path: Path) -> dict[str, bytes]:
    """The file's bytes and every record inside it, decompressed."""
    from mcap.reader import make_reader

    blobs = {f"{path.name} (file)": path.read_bytes()}
    with path.open("rb") as f:
        reader = make_reader(f)
        parts = []
        for schema, channel, message in reader.iter_messages():
            parts.append(message.data)
            parts.append(channel.topic.encode() + json.dumps(channel.metadata).encode())
            if schema is not None:
                parts.append(schema.data)
        blobs[f"{path.name} (records)"] = b"\n".join(parts)
    return blobs


def dir_blobs(path: Path) -> dict[str, bytes]:
    return {f"{path.name}/{p.name}": p.read_bytes() for p in sorted(path.iterdir())}


def test_replay_to_mcap_and_rosbag2_leaks_no_mac(tmp_path: Path) -> None:
    """``rfsas -vv replay CAPTURE --out run.mcap --foxglove 0 --ros2`` and ``--format
    rosbag2``: the files, stdout and the debug log hold no MAC of the capture."""
    capture = tmp_path / "known_macs.pcap"
    n_frames = write_known_capture(capture, time.time_ns())
    assert all(bytes.fromhex(f"{m:012x}") in capture.read_bytes() for m in KNOWN_MACS)
    blobs: dict[str, bytes] = {}
    # the MCAP run also serves Foxglove and publishes on loopback DDS (nobody listening)
    live = ["--foxglove", "0", "--ros2", "--ros2-interface", "lo", "--ros2-domain", "149"]
    runs = ((tmp_path / "run.mcap", live), (tmp_path / "run_bag", ["--format", "rosbag2"]))
    for out, extra in runs:
        cmd = [sys.executable, "-m", "rfsas_hw.cli.main", "-vv", "replay", str(capture)]
        cmd += [
            *STILL,
            "--calibration",
            str(CALIBRATION),
            "--out",
            str(out),
            "--sensor-id",
            "rsu-1",
        ]
        cmd += ["--pose", "1,2,90", *extra]
        proc = subprocess.run(cmd, capture_output=True, timeout=120, check=False)
        assert proc.returncode == 0, proc.stderr.decode(errors="replace")
        assert str(n_frames) in proc.stdout.decode()
        if extra is live:
            assert b"foxglove: open ws://127.0.0.1:" in proc.stderr
            assert b"ros2: publishing on domain 149" in proc.stderr
        blobs[f"{out.name} stdout"] = proc.stdout
        blobs[f"{out.name} stderr"] = proc.stderr
    blobs.update(mcap_blobs(tmp_path / "run.mcap"))
    blobs.update(dir_blobs(tmp_path / "run_bag"))
    # the recordings are real: bearings of every emitter, hashed
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with (tmp_path / "run.mcap").open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        ids = {
            b.emitter_id
            for _, ch, _, msg in reader.iter_decoded_messages()
            if ch.topic == topics.BEARINGS.name
            for b in msg.bearings
        }
    assert len(ids) == len(KNOWN_MACS)
    assert find_leaks(blobs, KNOWN_MACS) == []


def test_live_outputs_leak_no_mac(tmp_path: Path) -> None:
    """The bytes a Foxglove client receives and a DDS reader takes, from a pipeline fed
    frames of known MACs, hold none of them."""
    hasher = MacHasher(FixedNonce(bytes(range(32))))
    pipeline = SensorPipeline(load_calibration(CALIBRATION), hasher, "rsu-1", Pose(1, 2, 90))
    config = DdsConfig(domain_id=150 + (time.time_ns() // 1000) % 50, interface="lo")
    server = FoxgloveServer(port=0)
    publisher = DdsPublisher(config)
    from cyclonedds.qos import Policy, Qos
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic as DdsTopic

    from rfsas_hw.ros2.dds import _participant

    _, participant = _participant(config)
    readers = {
        t.name: DataReader(
            participant,
            DdsTopic(participant, t.dds_name, idl_class(t.typename), qos=qos_of(t)),
            qos=Qos(Policy.Reliability.Reliable(max_blocking_time=10**8), Policy.History.KeepAll),
        )
        for t in (topics.BEARINGS, topics.TF, topics.MARKERS)
    }
    ws = websocket.create_connection(server.url, subprotocols=["foxglove.sdk.v1"], timeout=5)
    frames: list[bytes] = []
    dds_bytes: list[bytes] = []
    dds_ids: set[str] = set()
    t0 = 0
    try:
        ws.recv()  # serverInfo
        channels = json.loads(ws.recv())["channels"]
        ws.send(
            json.dumps(
                {
                    "op": "subscribe",
                    "subscriptions": [{"id": c["id"], "channelId": c["id"]} for c in channels],
                }
            )
        )
        deadline = time.monotonic() + 20
        while not (
            all(ch.has_sinks() for ch in server._channels.values())
            and all(publisher.matched(t) for t in (topics.BEARINGS, topics.TF, topics.MARKERS))
        ):
            assert time.monotonic() < deadline
            time.sleep(0.02)
        ws.settimeout(0.2)
        stop = threading.Event()

        def read() -> None:
            while not stop.is_set():
                try:
                    frames.append(bytes(ws.recv_data()[1]))
                except websocket.WebSocketTimeoutException:
                    continue

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        scene = SensorScene(SceneSink([server, publisher]), lambda _s: pipeline.pose)
        t0 = time.time_ns()
        frames_in = known_frames(t0)
        for start in range(0, len(frames_in), 200):
            scene.on_bearings(pipeline.process(frames_in.select(slice(start, start + 200))))
            publisher.wait_for_acks(5.0)
        sent = sum(scene.sink.counts.values())
        while len(frames) < sent and time.monotonic() < deadline:
            time.sleep(0.05)
        for name, r in readers.items():
            for sample in r.take(N=10_000):
                dds_bytes.append(sample.serialize())
                if name == topics.BEARINGS.name:
                    dds_ids.update(b.emitter_id for b in sample.bearings)
        stop.set()
        reader.join(timeout=5)
    finally:
        ws.close()
        # close() leaves the socket open once the server's close frame has been read
        ws.shutdown()
        server.close()
        publisher.close()
    assert pipeline.stats.bearings > 500
    # every scene message reached the client (markers, TF, bearings) and the DDS readers
    assert len(frames) >= sent and len(dds_bytes) == sent
    # the published stream is real: bearings of every emitter, under its hashed id
    want = {f"{e:016x}" for e in hasher.hash_batch(np.array(KNOWN_MACS, np.uint64), np.full(6, t0))}
    assert dds_ids == want and len(want) == len(KNOWN_MACS)
    blobs = {f"foxglove frame {i}": f for i, f in enumerate(frames)}
    blobs.update({f"dds sample {i}": d for i, d in enumerate(dds_bytes)})
    assert find_leaks(blobs, KNOWN_MACS) == []
