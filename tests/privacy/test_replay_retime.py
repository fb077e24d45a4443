"""An old capture replayed with --retime feeds a live receiver; without it, it is refused."""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from pathlib import Path

from privhelp import CALIBRATION, write_known_capture

from rfsas_hw.link import Receiver, TrustedKeys
from rfsas_hw.link.keys import KeyStore

HOUR_NS = 3600 * 1_000_000_000


def _replay(capture: Path, keys: KeyStore, *extra: str) -> list[bytes]:
    listener = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    listener.bind(("127.0.0.1", 0))
    listener.settimeout(0.3)
    port = listener.getsockname()[1]
    cmd = [sys.executable, "-m", "rfsas_hw.cli.main", "replay", str(capture)]
    cmd += ["--calibration", str(CALIBRATION), "--sensor-id", "rsu-1", "--pose", "0,0,90"]
    cmd += ["--send", f"udp://127.0.0.1:{port}", "--keys", str(keys.path), *extra]
    datagrams: list[bytes] = []
    try:
        proc = subprocess.run(cmd, capture_output=True, timeout=120, check=False)
        while True:
            try:
                datagrams.append(listener.recv(65536))
            except TimeoutError:
                break
    finally:
        listener.close()
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")
    return datagrams


def test_retime_makes_an_hour_old_capture_acceptable(tmp_path: Path) -> None:
    capture = tmp_path / "old.pcap"
    write_known_capture(capture, time.time_ns() - HOUR_NS)
    keys = KeyStore.create(tmp_path / "rsu-1", "sensor")
    trust = TrustedKeys({"rsu-1": keys.signer().public_key})

    as_recorded = _replay(capture, keys)
    rx = Receiver(trust)
    assert as_recorded and all(rx.feed(d) is None for d in as_recorded)
    assert sum(rx.stats.rejected.values()) == len(as_recorded)

    retimed = _replay(capture, keys, "--retime")
    rx = Receiver(trust)
    got = [rx.feed(d) for d in retimed]
    assert retimed and all(g is not None for g in got), rx.stats
    newest = max(int(g.bearings.t_ns.max()) for g in got if g is not None)
    assert abs(newest - time.time_ns()) < 60 * 1_000_000_000
