"""``rfsas live`` keeps running across nonce epochs and an authority outage: it holds the
frames it cannot hash yet, drops and counts what expires, and recovers.

The sensor reads a pcap stream stamped with the wall clock (as ``tcpdump -w -``
would give it) and gets its nonces from an authority in this process, with 1 s
epochs (the shortest allowed). The authority starts late (the sensor's first
frames wait), hands out nonces, goes silent for longer than an epoch and its
grace period (at least one epoch's nonce is never delivered), and comes back.
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

from clihelp import STILL, rt_writer, write_calibration

from rfsas_hw.link.distribution import NonceDistributor
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.link.transport import open_transport
from rfsas_hw.privacy.epochs import EpochSchedule

EPOCH_S = 1.0
GRACE_S = 0.25  # what the sensor derives for a 1 s epoch: min(5, epoch/4)
RUN_S = 11.0
AUTHORITY_UP = [(1.0, 3.0), (7.5, RUN_S + 5)]
"""Seconds after the sensor listens when the authority sends (the current epoch's nonce and
the next one's); silent in between. The last nonce handed out before the outage is for an
epoch ending by 3 + 2·1 = 5 s, the first after it for one starting at 7.5 − 1 = 6.5 s or
later: every frame stamped in [5, 6.5) s can never be hashed."""
LOST = (5.0, 6.5)


def listening(port: int) -> bool:
    """True once someone (the sensor) has bound the UDP port."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return True
    return False


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_live_survives_epochs_and_an_authority_outage(tmp_path: Path) -> None:
    cal = write_calibration(tmp_path / "cal.yaml")
    auth = KeyStore.create(tmp_path / "rsu-0", "authority")
    sensor = KeyStore.create(tmp_path / "rsu-1", "sensor")
    sensor.trust.enroll(auth.card)
    auth.trust.enroll(sensor.card)
    authority = auth.nonce_authority()
    authority.schedule = EpochSchedule(EPOCH_S, GRACE_S)
    port = free_port()
    nonce_url = f"udp://127.0.0.1:{port}"
    dist = NonceDistributor(authority, {sensor.id: open_transport(nonce_url, "send")}, resend_s=0.2)
    out = tmp_path / "b.jsonl"
    proc = subprocess.Popen(
        [sys.executable, "-m", "rfsas_hw.cli.main", "live", "pcap:-", "--calibration", str(cal),
         "--keys", str(sensor.path), "--nonces", nonce_url, "--epoch", str(EPOCH_S),
         "--duration", str(RUN_S), "--out", str(out), "--json", *STILL],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )  # fmt: skip
    assert proc.stdin is not None
    start = time.monotonic()
    stop = threading.Event()
    up_wall_ns: list[int] = []

    def serve() -> None:
        while not stop.is_set() and not listening(port):
            stop.wait(0.05)
        up = time.monotonic()
        up_wall_ns.append(time.time_ns())
        while not stop.is_set():
            t = time.monotonic() - up
            if any(a <= t < b for a, b in AUTHORITY_UP):
                dist.tick()
            stop.wait(0.05)

    worker = threading.Thread(target=serve)
    worker.start()
    try:
        proc.stdin.write(rt_writer.pcap([])[:24])  # the stream's global header
        i = 0
        # the sensor ends itself after --duration; the bound only stops a hung one (a loaded
        # machine may take long to start it, and ending the stream early ends its input)
        while proc.poll() is None and time.monotonic() - start < RUN_S + 120:
            frame = rt_writer.mac80211_header(-50 - i % 5, -51 - i % 3) + rt_writer.dot11(
                ta=0x0200_0000_0001 + i % 3, seq=i % 4096
            )
            try:
                proc.stdin.write(rt_writer.pcap([(time.time_ns(), frame)])[24:])
                proc.stdin.flush()
            except BrokenPipeError:
                break  # the sensor's --duration is over
            i += 1
            time.sleep(0.02)
        stdout, stderr = proc.communicate(timeout=30)
    finally:
        stop.set()
        worker.join()
        dist.close()
        if proc.poll() is None:
            proc.kill()
    err = stderr.decode(errors="replace")
    assert proc.returncode == 0, err
    assert "Traceback" not in err and "nonce alarm" in err
    summary = json.loads(stdout)
    assert summary["stopped"] == "duration"
    # the outage cost at least one whole epoch's frames (about 50), counted, not a crash
    assert summary["rejected"].get("nonce_expired", 0) >= 10
    # frames waited at start-up and during the outage, and were released
    assert summary["nonces"]["alarms"] >= 2 and summary["nonces"]["released"] > 0
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(rows) == summary["bearings"] == summary["outputs"][str(out)]["written"]
    times_s = sorted((r["t_ns"] - up_wall_ns[0]) / 1e9 for r in rows)
    # bearings from before the outage, and again after the authority is back
    assert times_s[0] < AUTHORITY_UP[0][1]
    assert times_s[-1] > AUTHORITY_UP[1][0]
    # no frame of the epochs the authority never handed out became a bearing
    assert not [t for t in times_s if LOST[0] + 0.05 < t < LOST[1] - 0.05]
