"""No raw MAC through the broker: bearing payloads and topics, advisories, the broker's
files and log are free of the MACs the sensors heard."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from brokerhelp import Broker, Deployment
from fleethelp import ORIGIN

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "privacy"))

from privhelp import KNOWN_MACS, known_frames
from test_mac_leak import CALIBRATION, find_leaks

from rfsas_hw.backend.service import BackendService
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.df import load_calibration
from rfsas_hw.fleet.advisory import AdvisorySink
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.link import Publisher
from rfsas_hw.link.mqtt import open_mqtt
from rfsas_hw.pipeline import SensorPipeline
from rfsas_hw.privacy import FixedNonce, MacHasher
from rfsas_hw.records import Pose

POSES = {"rsu-1": Pose(1.0, 2.0, 90.0), "rsu-2": Pose(30.0, -10.0, 0.0)}


def test_nothing_through_the_broker_carries_a_mac(broker: Broker, deployment: Deployment) -> None:
    lat, lon = (float(v) for v in ORIGIN.split(","))
    tap = open_mqtt(broker.url("car-7", sub="rfsas/v1/vehicle/car-7/advisory"), "recv")
    bearings_tap = open_mqtt(broker.url("be-b", sub="rfsas/v1/bearing/#"), "recv")
    hasher = MacHasher(FixedNonce(bytes(range(32))))
    cal = load_calibration(CALIBRATION)
    backend = BackendService(
        sinks=[
            AdvisorySink.to_url(
                broker.url("be-a"),
                deployment.backends["be-a"].signer(),
                SiteOrigin(lat, lon),
                vehicle_id="car-7",
            )
        ],
        vehicle=VehicleState(0.0, -50.0, 0.0, 10.0),
    )
    t0 = time.time_ns()
    frames = known_frames(t0)
    for sid, pose in POSES.items():
        pipeline = SensorPipeline(cal, hasher, sid, pose)
        pub = Publisher.to_url(
            broker.url(sid, origin=ORIGIN),
            deployment.sensors[sid].signer(),
            pose,
            preauth=deployment.nonces,
        )
        for start in range(0, len(frames), 100):
            batch = pipeline.process(frames.select(slice(start, start + 100)))
            pub.on_bearings(batch)
            backend.on_bearings(batch, pose)
        pub.close()
    backend.step(t0 + 60_000_000)
    backend.close()
    blobs: dict[str, bytes] = {}
    for name, tap_t in (("bearing", bearings_tap), ("advisory", tap)):
        got = tap_t.recv_from(3)
        k = 0
        while got is not None:
            payload, topic = got
            blobs[f"{name} {k}"] = payload
            blobs[f"{name} topic {k}"] = (topic or "").encode()
            k += 1
            got = tap_t.recv_from(0.3)
        tap_t.close()
    assert sum(1 for k in blobs if k.startswith("bearing topic")) > 10
    assert any(k.startswith("advisory topic") for k in blobs)
    for path in deployment.files.root.rglob("*"):
        if path.is_file():
            blobs[str(path)] = path.read_bytes()
    blobs["broker log"] = broker.log.read_bytes()
    assert find_leaks(blobs, KNOWN_MACS) == []
