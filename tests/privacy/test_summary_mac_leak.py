"""The outputs added for scripts and operators carry no raw MAC: bearings on stdout
(``--out -``), ``--json`` summaries, failure lines, nonce-alarm log lines (at DEBUG)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from privhelp import CALIBRATION, KNOWN_MACS, STILL, write_known_capture
from test_mac_leak import find_leaks

from rfsas_hw.link.keys import KeyStore


def _run(args: list[str]) -> tuple[int, bytes]:
    proc = subprocess.run(
        [sys.executable, "-m", "rfsas_hw.cli.main", "-vv", *args],
        capture_output=True,
        timeout=120,
        check=False,
    )
    return proc.returncode, proc.stdout + proc.stderr


def test_summaries_and_stdout_bearings_leak_no_mac(tmp_path: Path) -> None:
    capture = tmp_path / "heard.pcap"
    write_known_capture(capture, time.time_ns())
    cal11 = tmp_path / "cal11.yaml"
    cal11.write_text(CALIBRATION.read_text().replace("channel: 6", "channel: 11"))
    sensor = KeyStore.create(tmp_path / "rsu-1", "sensor")
    sensor.trust.enroll(KeyStore.create(tmp_path / "rsu-0", "authority").card)
    blobs: dict[str, bytes] = {}
    runs = {
        "stdout bearings and json": ["replay", str(capture), "--calibration", str(CALIBRATION),
                                     "--out", "-", "--json", *STILL],
        "0 bearings": ["replay", str(capture), *STILL, "--calibration", str(cal11), "--json",
                       "--out", str(tmp_path / "none.jsonl")],
        "nothing sent": ["replay", str(capture), "--calibration", str(CALIBRATION), "--json",
                         "--keys", str(sensor.path), "--send", "udp://127.0.0.1:0", *STILL],
        # no authority answers: frames wait, the alarm is raised, the frames are dropped
        "nonce alarm": ["live", f"pcap:{capture}", "--calibration", str(CALIBRATION), "--json",
                        "--keys", str(sensor.path), "--nonces", "udp://127.0.0.1:0",
                        "--out", str(tmp_path / "b.csv"), *STILL],
    }  # fmt: skip
    codes = {}
    for name, args in runs.items():
        codes[name], blobs[name] = _run(args)
    assert codes["stdout bearings and json"] == 0
    assert codes["0 bearings"] == codes["nothing sent"] == codes["nonce alarm"] == 1
    assert b"nonce alarm" in blobs["nonce alarm"] and b'"bearings": 0' in blobs["nonce alarm"]
    for path in tmp_path.glob("*.jsonl"):
        blobs[path.name] = path.read_bytes()
    assert find_leaks(blobs, KNOWN_MACS) == []
