"""Sensors → broker → an active/active pair of ``rfsas backend`` processes (both given
the region of the sensors by a tile plan) → signed advisories → a vehicle. One backend
is killed: the vehicle misses no advisory."""

from __future__ import annotations

import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from brokerhelp import Broker, Deployment
from cryptography.hazmat.primitives.asymmetric import ec
from fleethelp import ORIGIN

from rfsas_hw.fleet.advisory import AdvisoryReceiver
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.link import Publisher
from rfsas_hw.link.mqtt import open_mqtt
from rfsas_hw.link.topics import TopicRouter
from rfsas_hw.records import BearingBatch, Pose

EMITTER_XY = (20.0, 30.0)
SENSOR_POSES = {"rsu-1": Pose(0.0, 0.0, 0.0), "rsu-2": Pose(40.0, 0.0, 0.0)}
EMITTER_ID = 0x0123_4567_89AB_CDEF


def _bearing(sender: str) -> BearingBatch:
    pose = SENSOR_POSES[sender]
    az = math.degrees(math.atan2(EMITTER_XY[0] - pose.x_m, EMITTER_XY[1] - pose.y_m)) % 360
    return BearingBatch(
        sensor_id=sender,
        t_ns=np.array([time.time_ns()], np.int64),
        azimuth_deg=np.array([az]),
        sigma_deg=np.array([1.0]),
        snr_db=np.array([25.0]),
        channel=np.array([6], np.int16),
        emitter=np.array([EMITTER_ID], np.uint64),
    )


class BackendCards:
    """The vehicle's enrolled backends (their cards' signing keys)."""

    def __init__(self, deployment: Deployment) -> None:
        self.keys = {b: s.card.sign_public for b, s in deployment.backends.items()}

    def backend_key(self, backend_id: str) -> ec.EllipticCurvePublicKey | None:
        return self.keys.get(backend_id)


def _tile_plan(path: Path) -> Path:
    """Both backends serve the region that holds both sensors; another group, elsewhere."""
    lat, lon = (float(v) for v in ORIGIN.split(","))
    router = TopicRouter(SiteOrigin(lat, lon))
    tiles = [router.tile_of(p.x_m, p.y_m) for p in SENSOR_POSES.values()]
    region = next(a for a in (tiles[0][:n] for n in range(16, 0, -1)) if tiles[1].startswith(a))
    assert len(region) >= 10
    elsewhere = region[:-1] + str((int(region[-1]) + 1) % 4)
    path.write_text(
        "groups:\n"
        f"  here: {{tiles: ['{region}'], members: [be-a, be-b]}}\n"
        f"  there: {{tiles: ['{elsewhere}'], members: [be-z]}}\n"
    )
    return path


def _backend(
    broker: Broker, deployment: Deployment, ident: str, vehicle: Path, log: Path
) -> subprocess.Popen[bytes]:
    cmd = [sys.executable, "-m", "rfsas_hw.cli.main", "backend"]
    cmd += ["--listen", broker.url(ident), "--tile-plan", str(_tile_plan(log.with_suffix(".yaml")))]
    cmd += ["--keys", str(deployment.backends[ident].path), "--vehicle", str(vehicle)]
    cmd += ["--advise", broker.url(ident), "--vehicle-id", "car-7", "--origin", ORIGIN]
    cmd += ["--no-table", "--duration", "30", "--accept-v1"]  # the sensors send version 1
    with log.open("wb") as fh:
        return subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT)


def test_one_backend_of_a_pair_killed_no_advisory_missed(
    broker: Broker, deployment: Deployment, tmp_path: Path
) -> None:
    vehicle = tmp_path / "car.yaml"
    vehicle.write_text("x_m: 20.0\ny_m: -40.0\nheading_deg: 0.0\nspeed_mps: 10.0\n")
    procs = {
        b: _backend(broker, deployment, b, vehicle, tmp_path / f"{b}.log") for b in ("be-a", "be-b")
    }
    pubs = [
        Publisher.to_url(broker.url(s, origin=ORIGIN), deployment.sensors[s].signer(), pose)
        for s, pose in SENSOR_POSES.items()
    ]
    vehicle_rx = open_mqtt(broker.url("car-7", sub="rfsas/v1/vehicle/car-7/advisory"), "recv")
    car = AdvisoryReceiver(BackendCards(deployment), vehicle_rx, vehicle_id="car-7")
    arrivals: list[tuple[float, str]] = []
    killed_at = None
    try:
        deadline = time.monotonic() + 40
        while time.monotonic() < deadline:
            for pub in pubs:
                pub.on_bearings(_bearing(pub.signer.sender_id))
            for msg in car.receive(timeout=0.05):
                arrivals.append((time.monotonic(), msg.sender_id))
            senders = {s for t, s in arrivals if killed_at is None or t < killed_at}
            if killed_at is None and senders == {"be-a", "be-b"} and len(arrivals) > 10:
                procs["be-a"].kill()
                killed_at = time.monotonic()
            if killed_at is not None and time.monotonic() - killed_at > 3.0:
                break
    finally:
        for pub in pubs:
            pub.close()
        vehicle_rx.close()
        for p in procs.values():
            if p.poll() is None:
                p.terminate()
            p.wait(10)
    logs = {b: (tmp_path / f"{b}.log").read_text() for b in procs}
    assert killed_at is not None, (car.stats, logs)
    after = [t for t, s in arrivals if t > killed_at]
    assert {s for t, s in arrivals if t > killed_at + 0.5} == {"be-b"}
    # be-b steps every 0.1 s: the vehicle is never without an advisory for a second
    times = [t for t, _ in arrivals if t > killed_at - 1.0]
    assert max(np.diff(times)) < 1.0, (np.diff(times).max(), logs)
    assert len(after) >= 20
    item = car.latest[f"{EMITTER_ID:016x}"][0]
    assert abs(item.x_m - EMITTER_XY[0]) < 2.0 and abs(item.y_m - EMITTER_XY[1]) < 2.0
    assert item.advisory in ("clear", "caution", "brake")
    assert car.stats.rejected.get("bad_signature", 0) == 0
