"""``--epoch`` on ``replay``/``live``: messages of a deployment with non-default epochs
are numbered as its backend expects, not rejected as ``wrong_epoch``."""

from __future__ import annotations

import socket
import sys
import time
from pathlib import Path

import pytest
from clihelp import REPO, run

from rfsas_hw.link import Receiver, ReceiverConfig, TrustedKeys
from rfsas_hw.link.keys import KeyStore

sys.path.insert(0, str(REPO / "tests" / "privacy"))
from privhelp import CALIBRATION, STILL, write_known_capture


def _send(tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str]) -> Receiver:
    t0 = time.time_ns()
    if (t0 // 10**9) % 30 > 25:  # stay clear of a 30 s boundary
        time.sleep(6)
        t0 = time.time_ns()
    capture = tmp_path / "heard.pcap"
    write_known_capture(capture, t0)
    keys = KeyStore.create(tmp_path / f"rsu-{len(extra)}", "sensor", "rsu-1")
    rx = Receiver(
        TrustedKeys({"rsu-1": keys.signer().public_key}),
        config=ReceiverConfig(epoch_s=30.0, grace_s=5.0, max_age_s=30.0),
    )
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(0.3)
        code, _, err = run(
            ["replay", str(capture), "--calibration", str(CALIBRATION), "--keys", str(keys.path),
             "--sensor-id", "rsu-1", "--send", f"udp://127.0.0.1:{sock.getsockname()[1]}",
             *STILL, *extra],
            capsys,
        )  # fmt: skip
        assert code == 0, err
        while True:
            try:
                rx.feed(sock.recv(65536))
            except TimeoutError:
                break
    return rx


def test_a_30_s_deployment_accepts_what_replay_epoch_30_sends(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rx = _send(tmp_path, capsys, ["--epoch", "30"])
    assert rx.stats.verified > 0 and rx.stats.rejected_total == 0, rx.stats


def test_without_epoch_the_same_backend_rejects_everything(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rx = _send(tmp_path, capsys, [])
    assert rx.stats.verified == 0 and rx.stats.rejected["wrong_epoch"] > 0, rx.stats
