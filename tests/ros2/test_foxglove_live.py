"""A client speaking the Foxglove WebSocket protocol receives the live scene of a run.

The client is written here from the protocol (JSON ``serverInfo``/``advertise``,
a ``subscribe`` op, binary message frames: opcode 1, subscription id u32,
log time u64, payload), not taken from the SDK. Every message the run
produced arrives, byte for byte what the MCAP recording of the same run
holds, and decodes with the schema the server advertised.
"""

from __future__ import annotations

import json
import struct
import threading
import time
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("foxglove", reason="needs the ros2 extra: pip install 'rfsas-hw[ros2]'")
websocket = pytest.importorskip(
    "websocket", reason="needs the dev extra: pip install 'rfsas-hw[dev]'"
)

from mcap_ros2._dynamic import generate_dynamic  # noqa: E402
from rosrun import read_mcap, run_backend  # noqa: E402

from rfsas_hw.ros2 import topics  # noqa: E402
from rfsas_hw.ros2.bag import McapFileWriter  # noqa: E402
from rfsas_hw.ros2.foxglove_live import FoxgloveServer  # noqa: E402

SUBPROTOCOL = "foxglove.sdk.v1"
DEADLINE_S = 20.0


class Client:
    """A minimal Foxglove WebSocket client: subscribe to everything, collect every frame."""

    def __init__(self, url: str) -> None:
        self.ws = websocket.create_connection(url, subprotocols=[SUBPROTOCOL], timeout=5)
        self.channels: dict[int, dict[str, Any]] = {}
        self.frames: list[tuple[int, int, bytes]] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.ended = ""

    def handshake(self, n_channels: int) -> dict[str, Any]:
        info = json.loads(self.ws.recv())
        assert info["op"] == "serverInfo"
        while len(self.channels) < n_channels:
            msg = json.loads(self.ws.recv())
            if msg["op"] == "advertise":
                self.channels.update({c["id"]: c for c in msg["channels"]})
        subs = [{"id": cid, "channelId": cid} for cid in self.channels]
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
        return info

    def start_reading(self) -> None:
        self.ws.settimeout(0.2)

        def loop() -> None:
            while not self._stop.is_set():
                try:
                    opcode, data = self.ws.recv_data()
                except websocket.WebSocketTimeoutException:
                    continue
                except (websocket.WebSocketConnectionClosedException, OSError) as err:
                    # the server went away: the test's count check says whether that was early
                    self.ended = f"{type(err).__name__} after {len(self.frames)} frames"
                    return
                if opcode == websocket.ABNF.OPCODE_BINARY and data[0] == 1:
                    sub, log_time = struct.unpack_from("<IQ", data, 1)
                    self.frames.append((sub, log_time, bytes(data[13:])))

        self._thread = threading.Thread(target=loop, daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self.ws.close()
        # close() leaves the socket open once the server's close frame has been read
        self.ws.shutdown()


class KeepOpen:
    """Hands messages to a writer; closing it is left to the test."""

    def __init__(self, writer: FoxgloveServer) -> None:
        self.writer = writer

    def write(self, topic: topics.Topic, log_time_ns: int, data: bytes) -> None:
        self.writer.write(topic, log_time_ns, data)

    def close(self) -> None:
        pass


def test_foxglove_client_receives_the_scene(tmp_path: Path) -> None:
    server = FoxgloveServer(port=0)
    assert server.url.startswith("ws://127.0.0.1:")
    client = Client(server.url)
    try:
        info = client.handshake(len(topics.ALL))
        assert info["name"] == "rfsas"
        advertised = {c["topic"]: c for c in client.channels.values()}
        assert set(advertised) == {t.name for t in topics.ALL}
        assert all(
            c["encoding"] == "cdr" and c["schemaEncoding"] == "ros2msg" for c in advertised.values()
        )
        client.start_reading()
        # the server needs a moment to register the subscriptions before data flows
        deadline = time.monotonic() + 5
        while not all(ch.has_sinks() for ch in server._channels.values()):
            assert time.monotonic() < deadline, "subscriptions never registered"
            time.sleep(0.02)
        # the run closes its writers at its end; the server must outlive it until the
        # client has everything, so the run gets a writer that does not close it
        run = run_backend(tmp_path, [McapFileWriter(tmp_path / "run.mcap"), KeepOpen(server)])
        expected = sum(run.sink.counts.values())
        deadline = time.monotonic() + DEADLINE_S
        while len(client.frames) < expected and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        client.close()
        server.close()

    assert len(client.frames) == expected, client.ended
    recorded = read_mcap(tmp_path / "run.mcap")
    got = sorted((client.channels[sub]["topic"], t, data) for sub, t, data in client.frames)
    assert got == sorted((m.topic, m.log_time_ns, m.data) for m in recorded)
    # each frame decodes with the schema the server advertised
    decoders = {
        c["topic"]: generate_dynamic(c["schemaName"], c["schema"])[c["schemaName"]]
        for c in client.channels.values()
    }
    scene: dict[str, list[Any]] = {}
    for topic, _, data in got:
        scene.setdefault(topic, []).append(decoders[topic](data))
    markers = {m.ns for arr in scene[topics.MARKERS.name] for m in arr.markers}
    assert {"sensors", "bearings/rsu-1", "fix_ellipses", "tracks", "advisories", "ego"} <= markers
    assert {t.child_frame_id for m in scene[topics.TF.name] for t in m.transforms} == {
        "rfsas/sensor/rsu-1",
        "rfsas/sensor/rsu-2",
        "rfsas/ego",
    }
    assert any(a.advisory == 2 for m in scene[topics.ASSESSMENTS.name] for a in m.assessments)


@pytest.mark.parametrize(("host", "warned"), [("127.0.0.1", False), ("0.0.0.0", True)])
def test_a_server_reachable_from_other_hosts_is_announced_with_a_warning(
    host: str, warned: bool
) -> None:
    from rfsas_hw.apps.ros2 import Ros2Options, live_writers

    writers: list[Any] = []
    lines: list[str] = []
    live_writers(Ros2Options(foxglove_port=0, foxglove_host=host), writers, lines)
    try:
        assert any("WARNING" in line and "no authentication" in line for line in lines) == warned
    finally:
        for writer in writers:
            writer.close()
