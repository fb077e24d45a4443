"""A deployment end to end: an authority hands nonces to two sensors running ``rfsas live``;
both hash the same MACs to the same ids, which a backend receives signed; a sensor
without the nonces does not."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
from privhelp import CALIBRATION, KNOWN_MACS, STILL, ArrivalStamps, write_known_capture

from rfsas_hw.link import Receiver, open_transport
from rfsas_hw.link.distribution import NonceDistributor
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.privacy import MacHasher


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def live_cmd(
    capture: Path, sensor: KeyStore, out: Path, send: str, nonces: str | None
) -> list[str]:
    cmd = [sys.executable, "-m", "rfsas_hw.cli.main", "live", f"pcap:{capture}"]
    cmd += [*STILL, "--calibration", str(CALIBRATION), "--out", str(out), "--sensor-id", sensor.id]
    cmd += ["--send", send, "--keys", str(sensor.path)]
    return cmd + (["--nonces", nonces] if nonces else [])


def _well_inside_an_epoch(epoch_s: float = 60.0, margin_s: float = 20.0) -> int:
    """Now, or the start of the next epoch if this one ends within ``margin_s``.

    The sensors start in subprocesses and wait for their nonces; a capture stamped
    just before a boundary could outlive its epoch's nonce (and grace) meanwhile.
    """
    now = time.time_ns()
    left_s = epoch_s - (now / 1e9) % epoch_s
    if left_s < margin_s:
        time.sleep(left_s + 0.1)
        now = time.time_ns()
    return now


def test_two_sensors_with_distributed_nonces_agree_on_ids(tmp_path: Path) -> None:
    t0 = _well_inside_an_epoch()
    capture = tmp_path / "heard.pcap"
    write_known_capture(capture, t0)
    auth = KeyStore.create(tmp_path / "rsu-0", "authority")
    sensors = [KeyStore.create(tmp_path / f"rsu-{i}", "sensor") for i in (1, 2, 3)]
    backend = KeyStore.create(tmp_path / "obu-1", "backend")
    for s in sensors:
        s.trust.enroll(auth.card)
        backend.trust.enroll(s.card)
    for s in sensors[:2]:  # rsu-3 is not enrolled with the authority
        auth.trust.enroll(s.card)
    authority = auth.nonce_authority()
    nonce_urls = {s.id: f"udp://127.0.0.1:{free_port()}" for s in sensors}
    trap = ArrivalStamps()
    dist = NonceDistributor(
        authority,
        {rid: open_transport(nonce_urls[rid], "send") for rid in authority.receivers},
        resend_s=0.2,  # the sensors bind their nonce ports after the first send
    )
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            dist.tick()
            stop.wait(0.05)

    worker = threading.Thread(target=serve)
    worker.start()
    outs = {s.id: tmp_path / f"{s.id}.jsonl" for s in sensors}
    procs: list[subprocess.Popen[bytes]] = []
    try:
        procs += [
            subprocess.Popen(
                live_cmd(capture, s, outs[s.id], trap.url, nonce_urls[s.id] if i < 2 else None),
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
            )
            for i, s in enumerate(sensors)
        ]
        trap.collect_while(lambda: any(p.poll() is None for p in procs))
        results = [p.communicate(timeout=60) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.communicate(timeout=60)
        stop.set()
        worker.join()
        dist.close()
        trap.close()
    for p, (_, err) in zip(procs, results, strict=True):
        assert p.returncode == 0, err.decode(errors="replace")
    rx = Receiver(backend.trust)
    got = [m for d, t in trap.datagrams if (m := rx.feed(d, t)) is not None]

    ids_by_sensor: dict[str, set[str]] = {}
    for m in got:
        ids_by_sensor.setdefault(m.sender_id, set()).update(
            f"{e:016x}" for e in m.bearings.emitter.tolist()
        )
    expected = MacHasher(authority).hash_batch(
        np.array(KNOWN_MACS, np.uint64), np.full(len(KNOWN_MACS), t0, np.int64)
    )
    want = {f"{e:016x}" for e in expected.tolist()}
    assert rx.stats.rejected_total == 0, rx.stats
    # the enrolled sensors agree with each other and with the authority, over the link ...
    assert ids_by_sensor["rsu-1"] == ids_by_sensor["rsu-2"] == want
    # ... and in their files
    for sid in ("rsu-1", "rsu-2"):
        assert {json.loads(line)["emitter"] for line in outs[sid].read_text().splitlines()} == want
    # a sensor hashing with its own random key shares no id with them
    assert len(ids_by_sensor["rsu-3"]) == len(KNOWN_MACS)
    assert not ids_by_sensor["rsu-3"] & want
