"""The backend's fix cues: an emitter at risk is cued to the vehicles on its channel."""

from __future__ import annotations

import math
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from backendhelp import bearing_towards
from click.testing import CliRunner
from cryptography.hazmat.primitives.asymmetric import ec

from rfsas_hw.backend.cuer import BackendCuer
from rfsas_hw.backend.service import BackendService
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.cli.backend import backend
from rfsas_hw.errors import LinkError
from rfsas_hw.link.cue import CueKind, decode_cue
from rfsas_hw.link.cue_receiver import CueReceiver
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.link.publisher import Publisher
from rfsas_hw.link.signing import Signer, TrustedKeys
from rfsas_hw.link.transport import open_transport
from rfsas_hw.records import BearingBatch, Pose

# the command test's scenario: two sensors, a pedestrian ahead of the car
sys.path.insert(0, str(Path(__file__).parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "link"))
from linkhelp import Kept
from test_cli_backend import EMITTER as CLI_EMITTER
from test_cli_backend import SENSORS, TARGET, VEHICLE_JSON, free_port, send_rounds

NOW_NS = 1_763_800_030_000_000_000
EMITTER = 0x0123456789ABCDEF


def bearing_to(sensor: str, xy: tuple[float, float], target: tuple[float, float]) -> BearingBatch:
    az = math.degrees(math.atan2(target[0] - xy[0], target[1] - xy[1])) % 360.0
    return BearingBatch(
        sensor_id=sensor,
        t_ns=np.array([NOW_NS - 50_000_000], np.int64),
        azimuth_deg=np.array([az]),
        sigma_deg=np.array([2.0]),
        snr_db=np.array([20.0]),
        channel=np.array([6], np.int16),
        emitter=np.array([EMITTER], np.uint64),
    )


def test_an_emitter_at_risk_gets_a_fix_cue_the_vehicle_accepts() -> None:
    signer = Signer("backend-1", ec.derive_private_key(0x4242, ec.SECP256R1()))
    link = Kept()
    cuer = BackendCuer(signer, link, clock=lambda: NOW_NS)
    backend = BackendService(sinks=[cuer], clock=lambda: NOW_NS)
    target = (1.0, 0.0)
    for sensor, xy in (("rsu-a", (-20.0, 10.0)), ("rsu-b", (20.0, 10.0))):
        backend.on_bearings(bearing_to(sensor, xy, target), Pose(xy[0], xy[1], 180.0))
    backend.set_vehicle(VehicleState(x_m=1.75, y_m=-40.0, heading_deg=0.0, speed_mps=15.0))
    assessments = backend.step(NOW_NS)
    assert assessments and assessments[0].advisory in ("brake", "caution") and link.sent
    cue = decode_cue(link.sent[0])
    assert cue.kind is CueKind.FIX and cue.emitter == EMITTER and cue.channel == 6
    assert cue.x_m == pytest.approx(1.0, abs=0.5) and cue.y_m == pytest.approx(0.0, abs=0.5)
    assert cue.a > 0 and cue.c > 0 and cue.a * cue.c > cue.b**2
    assert cue.risk == pytest.approx(assessments[0].risk, rel=1e-6)
    rx = CueReceiver(TrustedKeys({"backend-1": signer.public_key}))
    assert rx.feed(link.sent[0], NOW_NS) is not None
    # the next step within the interval sends nothing new
    backend.step(NOW_NS)
    assert len(link.sent) == 1 and cuer.stats.skipped["rate"] >= 1


def test_a_fix_older_than_a_cues_validity_is_not_cued() -> None:
    """A step that comes late (a loaded backend) must not send a cue that is already
    expired: the vehicle would refuse it as ``expired``."""
    signer = Signer("backend-1", ec.derive_private_key(0x4242, ec.SECP256R1()))
    link = Kept()
    late_ns = NOW_NS + 2_500_000_000  # the fix is 2.55 s old; cues are valid 2 s
    cuer = BackendCuer(signer, link, clock=lambda: late_ns, valid_s=2.0)
    backend = BackendService(sinks=[cuer], clock=lambda: NOW_NS)
    for sensor, xy in (("rsu-a", (-20.0, 10.0)), ("rsu-b", (20.0, 10.0))):
        backend.on_bearings(bearing_to(sensor, xy, (1.0, 0.0)), Pose(xy[0], xy[1], 180.0))
    backend.set_vehicle(VehicleState(x_m=1.75, y_m=-40.0, heading_deg=0.0, speed_mps=15.0))
    assessments = backend.step(NOW_NS)
    assert assessments and assessments[0].advisory in ("brake", "caution")
    assert link.sent == [] and cuer.stats.skipped["stale_fix"] == 1


def test_an_emitter_judged_clear_is_not_cued() -> None:
    signer = Signer("backend-1", ec.derive_private_key(0x4242, ec.SECP256R1()))
    link = Kept()
    cuer = BackendCuer(signer, link, clock=lambda: NOW_NS)
    backend = BackendService(sinks=[cuer], clock=lambda: NOW_NS)
    for sensor, xy in (("rsu-a", (-20.0, 10.0)), ("rsu-b", (20.0, 10.0))):
        backend.on_bearings(bearing_to(sensor, xy, (1.0, 0.0)), Pose(xy[0], xy[1], 180.0))
    backend.set_vehicle(VehicleState(x_m=1.75, y_m=-400.0, heading_deg=180.0, speed_mps=5.0))
    assert all(a.advisory == "clear" for a in backend.step(NOW_NS))
    assert link.sent == [] and cuer.stats.cues == 0
    with pytest.raises(LinkError):
        BackendCuer(signer, link, min_risk=1.5)


def test_backend_command_sends_fix_cues_the_vehicle_accepts(tmp_path: Path) -> None:
    """``rfsas backend --send-cues URL``: the pedestrian ahead of the car is cued."""
    backend_keys = KeyStore.create(tmp_path / "backend", "backend", "obu-1")
    stores = {sid: KeyStore.create(tmp_path / sid, "sensor", sid) for sid in SENSORS}
    for store in stores.values():
        backend_keys.trust.enroll(store.card)
    vehicle = tmp_path / "vehicle.json"
    vehicle.write_bytes(VEHICLE_JSON)
    cues_in = open_transport("udp://127.0.0.1:0", "recv")
    host, port = cues_in.address  # type: ignore[attr-defined]
    url = f"udp://127.0.0.1:{free_port()}"
    sender = threading.Thread(target=send_rounds, args=(url, stores, 0.2))
    sender.start()
    try:
        result = CliRunner().invoke(
            backend,
            ["--listen", url, "--keys", str(tmp_path / "backend"), "--vehicle", str(vehicle),
             "--send-cues", f"udp://{host}:{port}", "--duration", "2.0", "--no-table"],
        )  # fmt: skip
        sender.join()
        assert result.exit_code == 0, result.output
        got = []
        datagram = cues_in.recv(0.5)
        while datagram is not None:
            got.append(datagram)
            datagram = cues_in.recv(0)
    finally:
        cues_in.close()
    assert got
    trust = TrustedKeys({"obu-1": KeyStore.open(tmp_path / "backend").signer().public_key})
    rx = CueReceiver(trust)
    cues = [rx.feed(d, decode_cue(d).t_gen_us * 1000) for d in got]
    assert all(c is not None for c in cues), dict(rx.stats.rejected)
    c = cues[0]
    assert c is not None and c.kind is CueKind.FIX and c.emitter == CLI_EMITTER
    assert c.channel == 11 and c.x_m == pytest.approx(TARGET[0], abs=0.01)
    # the run's summary counts them
    summary = " ".join(result.output.split())
    assert f"cues.sent {len(got)}," in summary and "cues.failed 0," in summary


def test_backend_command_counts_cues_it_could_not_send(tmp_path: Path) -> None:
    """Every cue fails (a broadcast address the socket may not send to): the summary
    counts them and the run ends with exit 1 saying none got through."""
    backend_keys = KeyStore.create(tmp_path / "backend", "backend", "obu-1")
    stores = {sid: KeyStore.create(tmp_path / sid, "sensor", sid) for sid in SENSORS}
    for store in stores.values():
        backend_keys.trust.enroll(store.card)
    vehicle = tmp_path / "vehicle.json"
    vehicle.write_bytes(VEHICLE_JSON)
    url = f"udp://127.0.0.1:{free_port()}"
    sender = threading.Thread(target=send_rounds, args=(url, stores, 0.2))
    sender.start()
    try:
        result = CliRunner().invoke(
            backend,
            ["--listen", url, "--keys", str(tmp_path / "backend"), "--vehicle", str(vehicle),
             "--send-cues", "udp://255.255.255.255:9", "--duration", "2.0", "--no-table"],
        )  # fmt: skip
    finally:
        sender.join()
    summary = " ".join(result.output.split())
    assert result.exit_code == 1, result.output
    failed = int(summary.split("cues.failed ")[1].split(",")[0])
    assert failed > 0 and "cues.sent 0," in summary
    assert f"none of {failed} cues got through ({failed} send errors" in summary


def _late_rounds(url: str, stores: dict[str, KeyStore], age_s: float) -> None:
    """The command test's rounds, but every message already ``age_s`` old when sent."""
    time.sleep(0.2)
    shift = int(age_s * 1e9)
    pubs = {
        sid: Publisher(
            stores[sid].signer(),
            open_transport(url, "send"),
            pose,
            clock=lambda: time.time_ns() - shift,
        )
        for sid, pose in SENSORS.items()
    }
    try:
        for _ in range(20):
            now = time.time_ns() - shift
            for sid, pose in SENSORS.items():
                pubs[sid].on_bearings(bearing_towards(sid, pose, TARGET, CLI_EMITTER, now))
            time.sleep(0.1)
    finally:
        for pub in pubs.values():
            pub.close()


def test_cues_move_to_the_fallback_while_the_link_is_late(tmp_path: Path) -> None:
    """``--send-cues A --cues-fallback B``: with every message arriving 300 ms old (over
    the 100 ms budget) the latency alarm rises and the cues go out on B."""
    backend_keys = KeyStore.create(tmp_path / "backend", "backend", "obu-1")
    stores = {sid: KeyStore.create(tmp_path / sid, "sensor", sid) for sid in SENSORS}
    for store in stores.values():
        backend_keys.trust.enroll(store.card)
    vehicle = tmp_path / "vehicle.json"
    vehicle.write_bytes(VEHICLE_JSON)
    primary = open_transport("udp://127.0.0.1:0", "recv")
    secondary = open_transport("udp://127.0.0.1:0", "recv")
    urls = [f"udp://{t.address[0]}:{t.address[1]}" for t in (primary, secondary)]  # type: ignore[attr-defined]
    url = f"udp://127.0.0.1:{free_port()}"
    sender = threading.Thread(target=_late_rounds, args=(url, stores, 0.3))
    sender.start()
    try:
        result = CliRunner().invoke(
            backend,
            ["--listen", url, "--keys", str(tmp_path / "backend"), "--vehicle", str(vehicle),
             "--send-cues", urls[0], "--cues-fallback", urls[1], "--duration", "2.5",
             "--no-table"],
        )  # fmt: skip
        sender.join()
        assert result.exit_code == 0, result.output
        assert secondary.recv(0.5) is not None, "no cue went out of band"
    finally:
        primary.close()
        secondary.close()
