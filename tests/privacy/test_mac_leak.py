"""No raw MAC leaves the sensor: not on the network, not in log lines, not in output files.

A sensor pipeline processes frames from known MACs while everything it emits
is captured: every UDP datagram (a real socket), every log record at DEBUG,
every output file and the statistics a command would print. Then each MAC is
searched for in every form it could take: hex with any separator or none,
upper or lower case, Cisco dotted groups, raw bytes in either order, decimal,
base64.
"""

from __future__ import annotations

import base64
import json
import logging
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from cryptography.hazmat.primitives.asymmetric import ec
from privhelp import KNOWN_MACS, STILL, ArrivalStamps, known_frames, write_known_capture

from rfsas_hw.df import load_calibration
from rfsas_hw.link import Publisher, Receiver, ReceiverConfig, Signer, TrustedKeys
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.output import BearingWriter
from rfsas_hw.pipeline import SensorPipeline
from rfsas_hw.privacy import FixedNonce, MacHasher
from rfsas_hw.records import Pose
from rfsas_hw.stream import Fanout

REPO = Path(__file__).resolve().parents[2]
CALIBRATION = REPO / "calibration" / "example_cal.yaml"


def mac_patterns(mac: int) -> list[re.Pattern[bytes]]:
    """Every form of ``mac`` this test looks for, as byte regexes."""
    raw = mac.to_bytes(6, "big")
    pairs = [f"{b:02x}".encode() for b in raw]
    any_sep = rb"[^0-9A-Fa-f]{0,3}"
    pats = [
        # hex, any separator (or none) between bytes, any case
        re.compile(any_sep.join(pairs), re.IGNORECASE),
        # Cisco style aabb.ccdd.eeff, and any other grouping by two bytes
        re.compile(any_sep.join(raw[i : i + 2].hex().encode() for i in (0, 2, 4)), re.IGNORECASE),
        # raw bytes, network order and reversed (a little-endian integer dump)
        re.compile(re.escape(raw)),
        re.compile(re.escape(raw[::-1])),
        # the integer in decimal, as a careless log line might print it
        re.compile(rb"(?<![0-9])" + str(mac).encode() + rb"(?![0-9])"),
        # base64 of the 6 bytes (aligned, so it is a fixed 8-character string)
        re.compile(re.escape(base64.b64encode(raw))),
    ]
    return pats


def find_leaks(blobs: dict[str, bytes], macs: list[int]) -> list[str]:
    hits = []
    for mac in macs:
        for pat in mac_patterns(mac):
            for name, blob in blobs.items():
                m = pat.search(blob)
                if m:
                    hits.append(f"{mac:012x} as {m.group(0)!r} in {name}")
    return hits


@pytest.mark.parametrize(
    "leak",
    [
        b"from 3c:22:fb:01:02:ab heard",
        b"mac=3C-22-FB-01-02-AB",
        b"3c22fb0102ab",
        b"3C22.FB01.02AB",
        b"3c 22 fb 01 02 ab",
        b"\x00\x00\x3c\x22\xfb\x01\x02\xab",
        b"\xab\x02\x01\xfb\x22\x3c\x00\x00",
        str(0x3C22FB0102AB).encode(),
        base64.b64encode(bytes.fromhex("3c22fb0102ab")),
    ],
)
def test_the_search_finds_every_form(leak: bytes) -> None:
    assert find_leaks({"planted": b"xx" + leak + b"yy"}, [0x3C22FB0102AB])


class Capture(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(self.format(record))


def test_library_sensor_leaks_no_mac(tmp_path: Path) -> None:
    listener = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    listener.bind(("127.0.0.1", 0))
    listener.settimeout(0.05)
    url = f"udp://127.0.0.1:{listener.getsockname()[1]}"
    capture = Capture()
    root = logging.getLogger()
    old_level = root.level
    root.addHandler(capture)
    root.setLevel(logging.DEBUG)
    signer = Signer("rsu-1", ec.generate_private_key(ec.SECP256R1()))
    hasher = MacHasher(FixedNonce(bytes(range(32))))
    pipeline = SensorPipeline(load_calibration(CALIBRATION), hasher, "rsu-1", Pose(1, 2, 90))
    jsonl, csv = tmp_path / "bearings.jsonl", tmp_path / "bearings.csv"
    fan = Fanout(
        [BearingWriter(jsonl), BearingWriter(csv), Publisher.to_url(url, signer, Pose(1, 2, 90))]
    )
    datagrams: list[bytes] = []
    try:
        t0 = time.time_ns()
        frames = known_frames(t0)
        for start in range(0, len(frames), 100):
            fan.on_bearings(pipeline.process(frames.select(slice(start, start + 100))))
        fan.close()
        while True:
            try:
                datagrams.append(listener.recv(65536))
            except TimeoutError:
                break
    finally:
        root.removeHandler(capture)
        root.setLevel(old_level)
        listener.close()

    # the capture is real: bearings for every MAC went out signed, and decode to hashed ids
    trust = TrustedKeys({"rsu-1": signer.public_key})
    rx = Receiver(trust, config=ReceiverConfig(max_age_s=60.0))
    got = [rx.feed(d) for d in datagrams]
    assert datagrams and all(g is not None for g in got), rx.stats
    sent_ids = set(np.concatenate([g.bearings.emitter for g in got if g]).tolist())
    want_ids = set(hasher.hash_batch(np.array(KNOWN_MACS, np.uint64), np.full(6, t0)).tolist())
    assert sent_ids == want_ids
    assert any("sent seq" in line for line in capture.lines)
    assert len(jsonl.read_text().splitlines()) == pipeline.stats.bearings > 500

    blobs = {f"datagram {i}": d for i, d in enumerate(datagrams)}
    blobs["log"] = "\n".join(capture.lines).encode()
    blobs["jsonl"] = jsonl.read_bytes()
    blobs["csv"] = csv.read_bytes()
    blobs["stats"] = json.dumps(
        {"pipeline": pipeline.stats.as_dict(), "receiver": rx.stats.as_dict()}, default=str
    ).encode()
    assert find_leaks(blobs, KNOWN_MACS) == []


def test_replay_command_end_to_end_leaks_no_mac(tmp_path: Path) -> None:
    """``rfsas -vv replay CAPTURE --out … --send udp://… --keys …``: stdout, stderr (debug
    log), the output file and every datagram are free of the capture's MACs."""
    capture = tmp_path / "known_macs.pcap"
    n_frames = write_known_capture(capture, time.time_ns())
    assert all(bytes.fromhex(f"{m:012x}") in capture.read_bytes() for m in KNOWN_MACS)
    keys = KeyStore.create(tmp_path / "rsu-1", "sensor")
    out = tmp_path / "bearings.jsonl"
    with ArrivalStamps() as trap:
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
        cmd += ["--pose", "1,2,90", "--send", trap.url, "--keys", str(keys.path)]
        out_log, err_log = tmp_path / "stdout", tmp_path / "stderr"
        with (
            out_log.open("wb") as so,
            err_log.open("wb") as se,
            subprocess.Popen(cmd, stdout=so, stderr=se) as running,
        ):
            try:
                trap.collect_while(lambda: running.poll() is None)
            finally:
                if running.poll() is None:
                    running.kill()
                returncode = running.wait(timeout=60)
        proc = subprocess.CompletedProcess(
            cmd, returncode, out_log.read_bytes(), err_log.read_bytes()
        )
    datagrams = [d for d, _ in trap.datagrams]
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")
    # the run was real: frames read, debug logging on, bearings written and sent signed
    assert str(n_frames) in proc.stdout.decode()
    assert b"DEBUG" in proc.stderr and b"sent seq" in proc.stderr
    lines = out.read_text().splitlines()
    assert len(lines) > 0.8 * n_frames
    rx = Receiver(TrustedKeys({"rsu-1": keys.signer().public_key}))
    got = [rx.feed(d, t_arrived) for d, t_arrived in trap.datagrams]
    assert datagrams and all(g is not None for g in got), rx.stats
    assert sum(len(g.bearings) for g in got if g) == len(lines)
    assert {json.loads(line)["emitter"] for line in lines} == {
        f"{e:016x}" for g in got if g for e in g.bearings.emitter.tolist()
    }

    blobs = {f"datagram {i}": d for i, d in enumerate(datagrams)}
    blobs.update(stdout=proc.stdout, stderr=proc.stderr, jsonl=out.read_bytes())
    assert find_leaks(blobs, KNOWN_MACS) == []
