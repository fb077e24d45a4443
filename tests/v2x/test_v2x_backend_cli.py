"""``rfsas backend --cpm``: a vehicle's backend sends its tracks as CPMs from the vehicle."""

from __future__ import annotations

import math
import sys
import threading
import time
from pathlib import Path

import numpy as np
from click.testing import CliRunner
from pycrate_cpm import PycrateCpm

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "backend"))

from backendhelp import bearing_towards

from rfsas_hw.cli.backend import backend
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.link import Publisher
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.records import Pose
from rfsas_hw.v2x.listen import CpmListener

EMITTER = 0xC0FF_EE00_0000_0042
TARGET = np.array([-6.0, 22.0])
SENSORS = {"rsu-n": Pose(-35.0, 10.0, 90.0), "rsu-s": Pose(25.0, -5.0, 0.0)}
ORIGIN = SiteOrigin(52.2053, 0.1218)


def send_rounds(url: str, stores: dict[str, KeyStore], stop: threading.Event) -> None:
    """Bearings every 0.1 s until ``stop`` (at most 60 s): the command may take a few
    seconds to start on a loaded machine, and what arrives before it runs is stale."""
    pubs = {sid: Publisher.to_url(url, stores[sid].signer(), pose) for sid, pose in SENSORS.items()}
    try:
        for _ in range(600):
            if stop.wait(0.1):
                break
            now = time.time_ns()
            for sid, pose in SENSORS.items():
                pubs[sid].on_bearings(bearing_towards(sid, pose, TARGET, EMITTER, now))
    finally:
        for pub in pubs.values():
            pub.close()


def test_backend_sends_cpms_from_the_vehicle(tmp_path: Path, pycrate_cpm: PycrateCpm) -> None:
    backend_keys = KeyStore.create(tmp_path / "backend", "backend", "obu-1")
    stores = {sid: KeyStore.create(tmp_path / sid, "sensor", sid) for sid in SENSORS}
    for store in stores.values():
        backend_keys.trust.enroll(store.card)
    vehicle = tmp_path / "vehicle.json"
    vehicle.write_text('{"x_m": -12, "y_m": 22, "heading_deg": 90, "speed_mps": 8}')
    listener = CpmListener("udp://127.0.0.1:0")
    host, port = listener.address  # type: ignore[misc]
    link = CpmListener("udp://127.0.0.1:0")  # only to find a free port for the link
    link_port = link.address[1]  # type: ignore[index]
    link.close()
    url = f"udp://127.0.0.1:{link_port}"
    stop = threading.Event()
    sender = threading.Thread(target=send_rounds, args=(url, stores, stop))
    sender.start()
    try:
        result = CliRunner().invoke(
            backend,
            [
                "--listen", url, "--keys", str(tmp_path / "backend"), "--vehicle", str(vehicle),
                "--origin", "52.2053,0.1218", "--no-table", "--duration", "3.5",
                "--cpm", f"udp://{host}:{port}?btp=1", "--cpm-station-id", "77",
                "--cpm-from-vehicle",
            ],
        )  # fmt: skip
        stop.set()
        sender.join(timeout=10)
        assert result.exit_code == 0, result.output
        assert "cpm.sent" in result.output and "cpm.dropped 0" in result.output
        cpms = []
        while (got := listener.receive(timeout=0.5)) is not None:
            assert got.cpm is not None, got.error
            cpms.append(got)
    finally:
        stop.set()
        sender.join(timeout=10)
        listener.close()
    assert cpms
    lat, lon, _ = ORIGIN.to_geodetic(-12.0, 22.0)
    with_objects = 0
    for got in cpms:
        tree = got.cpm
        assert tree is not None and tree["header"]["stationId"] == 77
        assert pycrate_cpm.reencode(got.data) == got.data
        assert tree["containers"]["originatingVehicleContainer"]["orientationAngle"]["value"] == 900
        ref = tree["managementContainer"]["referencePosition"]
        assert (
            abs(ref["latitude"] - float(lat) * 1e7) <= 1
            and abs(ref["longitude"] - float(lon) * 1e7) <= 1
        )
        objects = tree["containers"].get("perceivedObjectContainer", {}).get("perceivedObjects", [])
        for obj in objects:
            with_objects += 1
            # the emitter is 6 m east of the vehicle, at the same northing
            x = obj["position"]["xCoordinate"]["value"] / 100
            y = obj["position"]["yCoordinate"]["value"] / 100
            assert math.hypot(x - 6.0, y - 0.0) < 0.05
    assert with_objects > 0, (result.output, [c.cpm for c in cpms][:3])
