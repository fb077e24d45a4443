"""The sensor application from Python: a capture into a file and signed messages,
hashed ids only; the outputs it refuses; it runs once."""

from __future__ import annotations

import json
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from privhelp import CALIBRATION, KNOWN_MACS, ArrivalStamps, write_known_capture

from rfsas_hw.apps.sensor import SensorApp, SensorAppConfig
from rfsas_hw.errors import ConfigError
from rfsas_hw.link import Receiver, TrustedKeys
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.privacy import MacHasher
from rfsas_hw.privacy.hashing import DerivedNonces
from rfsas_hw.records import Pose


def _mac_forms(mac: int) -> list[bytes]:
    raw = mac.to_bytes(6, "big")
    return [raw.hex().encode(), raw.hex(":").encode(), raw.hex("-").encode(), raw]


def test_a_capture_becomes_hashed_bearings_in_a_file_and_on_the_link(tmp_path: Path) -> None:
    t0 = time.time_ns()
    capture = tmp_path / "heard.pcap"
    n_frames = write_known_capture(capture, t0)
    secret = tmp_path / "secret.key"
    secret.write_bytes(bytes(range(32)))
    secret.chmod(0o600)
    keys = KeyStore.create(tmp_path / "rsu-1", "sensor", "rsu-1")
    out = tmp_path / "bearings.jsonl"
    with ArrivalStamps() as trap:
        config = SensorAppConfig(
            spec=f"pcap:{capture}",
            calibration=CALIBRATION,
            prove_motion_deg=0.0,  # the capture's transmitters stand still
            sensor_id="rsu-1",
            pose=Pose(0.0, 0.0, 90.0),
            nonce_secret=secret,
            keys_dir=keys.path,
            out=out,
            inputs=(capture, CALIBRATION, secret),
            send=(trap.url,),
            retime=True,  # stamped now, so that a live receiver takes them
        )
        app = SensorApp(config)
        done = threading.Event()
        collector = threading.Thread(target=trap.collect_while, args=(lambda: not done.is_set(),))
        collector.start()
        try:
            summary = app.run()
        finally:
            done.set()
            collector.join(timeout=60)
    assert not collector.is_alive()
    assert summary.frames == n_frames and summary.bearings > 500
    lines = out.read_text().splitlines()
    assert len(lines) == summary.bearings
    # the ids are the deployment's hashes of the capture's MACs (in the epoch of the
    # capture or of the replay), the same in the file and on the link
    hasher = MacHasher(DerivedNonces.from_file(secret))
    macs = np.array(KNOWN_MACS, np.uint64)
    hashed = [
        {f"{e:016x}" for e in hasher.hash_batch(macs, np.full(len(macs), t, np.int64)).tolist()}
        for t in (t0, time.time_ns())
    ]
    in_file = {json.loads(line)["emitter"] for line in lines}
    assert in_file in hashed
    rx = Receiver(TrustedKeys({"rsu-1": keys.signer().public_key}))
    got = [m for d, t in trap.datagrams if (m := rx.feed(d, t)) is not None]
    assert got and rx.stats.rejected_total == 0, rx.stats
    assert {f"{e:016x}" for m in got for e in m.bearings.emitter.tolist()} == in_file
    blobs = [out.read_bytes(), *(d for d, _ in trap.datagrams)]
    assert not [m for m in KNOWN_MACS for f in _mac_forms(m) for b in blobs if f in b.lower()]


def test_outputs_it_refuses_and_a_second_run(tmp_path: Path) -> None:
    capture = tmp_path / "heard.pcap"
    write_known_capture(capture, time.time_ns())
    base = SensorAppConfig(
        spec=f"pcap:{capture}",
        calibration=CALIBRATION,
        inputs=(capture,),
        prove_motion_deg=0.0,  # the capture's transmitters stand still
    )
    with pytest.raises(ConfigError, match="nothing to do"):
        SensorApp(base)
    with pytest.raises(ConfigError, match="also an input"):
        SensorApp(replace(base, out=capture))
    with pytest.raises(ConfigError, match="--send needs --keys"):
        SensorApp(replace(base, send=("udp://127.0.0.1:9",)))
    with pytest.raises(ConfigError, match="calibration"):
        SensorApp(replace(base, calibration=None))
    out = tmp_path / "b.jsonl"
    with SensorApp(replace(base, out=out)) as app:
        assert app.run().bearings > 0
        with pytest.raises(ConfigError, match="runs once"):
            app.run()
    # an existing result is kept unless asked to replace it
    with pytest.raises(ConfigError, match="exists"):
        SensorApp(replace(base, out=out))
