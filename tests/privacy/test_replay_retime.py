"""An old capture replayed with --retime feeds a live receiver; without it, it is refused."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from privhelp import CALIBRATION, STILL, ArrivalStamps, write_known_capture

from rfsas_hw.link import Receiver, TrustedKeys
from rfsas_hw.link.keys import KeyStore

HOUR_NS = 3600 * 1_000_000_000


def _replay(capture: Path, keys: KeyStore, tmp_path: Path, *extra: str) -> list[tuple[bytes, int]]:
    """What ``rfsas replay --send`` sends, each datagram with its arrival time (UTC ns)."""
    with ArrivalStamps() as trap, (tmp_path / "replay.log").open("wb") as log:
        cmd = [sys.executable, "-m", "rfsas_hw.cli.main", "replay", str(capture)]
        cmd += [
            *STILL,
            "--calibration",
            str(CALIBRATION),
            "--sensor-id",
            "rsu-1",
            "--pose",
            "0,0,90",
        ]
        cmd += ["--send", trap.url, "--keys", str(keys.path), *extra]
        with subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT) as proc:
            try:
                trap.collect_while(lambda: proc.poll() is None)
            finally:
                if proc.poll() is None:
                    proc.kill()
                returncode = proc.wait(timeout=60)
    assert returncode == 0, (tmp_path / "replay.log").read_text(errors="replace")
    return trap.datagrams


def test_retime_makes_an_hour_old_capture_acceptable(tmp_path: Path) -> None:
    capture = tmp_path / "old.pcap"
    write_known_capture(capture, time.time_ns() - HOUR_NS)
    keys = KeyStore.create(tmp_path / "rsu-1", "sensor")
    trust = TrustedKeys({"rsu-1": keys.signer().public_key})

    as_recorded = _replay(capture, keys, tmp_path)
    rx = Receiver(trust)
    assert as_recorded and all(rx.feed(d, t) is None for d, t in as_recorded)
    assert set(rx.stats.rejected) <= {"stale", "wrong_epoch"}, rx.stats  # too old, not forged
    assert sum(rx.stats.rejected.values()) == len(as_recorded)

    retimed = _replay(capture, keys, tmp_path, "--retime")
    rx = Receiver(trust)
    got = [rx.feed(d, t) for d, t in retimed]
    assert retimed and all(g is not None for g in got), rx.stats
    newest = max(int(g.bearings.t_ns.max()) for g in got if g is not None)
    assert abs(newest - max(t for _, t in retimed)) < 60 * 1_000_000_000
