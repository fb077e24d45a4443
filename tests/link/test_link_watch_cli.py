"""``rfsas link watch``: what a user sees of the link, including the alarm."""

from __future__ import annotations

import json
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from linkhelp import bearings
from rich.console import Console

from rfsas_hw.cli.link import render
from rfsas_hw.cli.main import main
from rfsas_hw.link import Publisher, Receiver, open_transport
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.records import Pose


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_watch_shows_senders_rejections_and_the_alarm(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sensor = KeyStore.create(tmp_path / "rsu-1", "sensor")
    backend = KeyStore.create(tmp_path / "obu-1", "backend")
    backend.trust.enroll(sensor.card)
    url = f"udp://127.0.0.1:{free_port()}"
    stop = threading.Event()

    def send() -> None:
        # a sensor whose messages are 300 ms old when sent: over the 100 ms budget
        pub = Publisher(
            sensor.signer(),
            open_transport(url, "send"),
            Pose(0, 0, 0),
            clock=lambda: time.time_ns() - 300_000_000,
        )
        junk = open_transport(url, "send")
        while not stop.wait(0.02):
            now = time.time_ns()
            pub.on_bearings(bearings("rsu-1", 2, now - 300_000_000))
            junk.send(b"not a message")
        pub.close()
        junk.close()

    worker = threading.Thread(target=send)
    worker.start()
    try:
        main(
            [
                "link",
                "watch",
                "--listen",
                url,
                "--keys",
                str(backend.path),
                "--expect",
                "rsu-9",
                "--duration",
                "1.5",
                "--json",
            ]
        )
    except SystemExit as exc:
        assert not exc.code
    finally:
        stop.set()
        worker.join()
    out = capsys.readouterr().out
    status = json.loads(out.strip().splitlines()[-1])
    assert status["alarm"] is True
    assert status["senders"]["rsu-1"]["state"] == "late"
    assert status["senders"]["rsu-1"]["messages"] > 10
    assert status["senders"]["rsu-1"]["p99_ms"] > 250
    assert status["senders"]["rsu-9"]["state"] == "silent"
    assert status["stats"]["rejected.bad_magic"] > 10
    assert np.isfinite(status["senders"]["rsu-1"]["p99_ms"])


def test_render_shows_the_table(tmp_path: Path) -> None:
    backend = KeyStore.create(tmp_path / "obu-1", "backend")
    rx = Receiver(backend.trust)
    rx.latency.expect(["rsu-1"], 0)
    rx.feed(b"junk datagram", 0)
    console = Console(record=True, width=120)
    console.print(render(rx, 2_000_000_000))
    text = console.export_text()
    assert "rsu-1" in text and "silent" in text
    assert "rejected: bad_magic 1" in text and "ALARM" in text
