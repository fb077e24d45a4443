"""The backend service end to end: signed bearings over real UDP to fixes and risk."""

from __future__ import annotations

import json
import socket
import time
from pathlib import Path

import numpy as np
import pytest
from cryptography.hazmat.primitives.asymmetric import ec

from rfsas_hw.angles import math_rad_to_compass
from rfsas_hw.backend.association import AssociationConfig
from rfsas_hw.backend.service import (
    BackendConfig,
    BackendService,
    JsonlSink,
    load_backend_config,
)
from rfsas_hw.backend.triangulation import bearing_crb
from rfsas_hw.backend.vehicle import VehicleFeed, VehicleState, load_vehicle
from rfsas_hw.errors import ConfigError
from rfsas_hw.link import (
    Publisher,
    Receiver,
    SafetyMessage,
    Signer,
    TrustedKeys,
    UdpTransport,
    open_transport,
)
from rfsas_hw.privacy.epochs import EpochSchedule
from rfsas_hw.records import BearingBatch, Pose

S = 1_000_000_000
EMITTER = 0x5EED_0000_0000_0001
OTHER = 0x5EED_0000_0000_0002
SIGMA_DEG = 1.0
TARGET = np.array([4.0, 15.0])
STATIONS = {"rsu-a": Pose(-30.0, 0.0, 45.0), "rsu-b": Pose(30.0, 0.0, 315.0)}


def true_azimuth(pose: Pose, target: np.ndarray) -> float:
    return float(math_rad_to_compass(np.arctan2(target[1] - pose.y_m, target[0] - pose.x_m)))


def bearing_batch(sensor: str, t_ns: int, az: list[float], emitters: list[int]) -> BearingBatch:
    n = len(az)
    return BearingBatch(
        sensor_id=sensor,
        t_ns=np.full(n, t_ns, np.int64),
        azimuth_deg=np.array(az),
        sigma_deg=np.full(n, SIGMA_DEG),
        snr_db=np.full(n, 25.0),
        channel=np.full(n, 6, np.int16),
        emitter=np.array(emitters, np.uint64),
    )


def test_two_sensors_over_udp_give_the_fix_and_forgeries_and_replays_are_counted(
    tmp_path: Path,
) -> None:
    rng = np.random.default_rng(60)
    keys = {sid: ec.generate_private_key(ec.SECP256R1()) for sid in STATIONS}
    trust = TrustedKeys({sid: k.public_key() for sid, k in keys.items()})
    rx = Receiver.listen("udp://127.0.0.1:0", trust)
    assert isinstance(rx.transport, UdpTransport)
    url = f"udp://127.0.0.1:{rx.transport.address[1]}"
    out = tmp_path / "backend.jsonl"
    service = BackendService(
        BackendConfig(association=AssociationConfig(window_s=0.5)), sinks=[JsonlSink(out)]
    )
    publishers = {
        sid: Publisher.to_url(url, Signer(sid, keys[sid]), pose) for sid, pose in STATIONS.items()
    }
    raw = open_transport(url, "send")
    now = time.time_ns()
    try:
        # three rounds of honest bearings, 50 ms apart
        for k in range(3):
            t = now - (3 - k) * 50_000_000
            for sid, pose in STATIONS.items():
                az = true_azimuth(pose, TARGET) + SIGMA_DEG * rng.standard_normal()
                publishers[sid].on_bearings(bearing_batch(sid, t, [az], [EMITTER]))
        # a forgery: rsu-a's id, an unenrolled key, a bearing that would move the fix far away
        forged_az = true_azimuth(STATIONS["rsu-a"], np.array([-20.0, 60.0]))
        forged = bearing_batch("rsu-a", now, [forged_az], [EMITTER])
        epoch = EpochSchedule().epoch_of(now)
        msg = SafetyMessage("rsu-a", STATIONS["rsu-a"], now // 1000, 1, epoch, forged)
        raw.send(Signer("rsu-a", ec.generate_private_key(ec.SECP256R1())).encode(msg))
        # a replay: a genuinely signed message about another emitter, sent twice
        genuine = SafetyMessage(
            "rsu-b", STATIONS["rsu-b"], now // 1000, 12345, epoch,
            bearing_batch("rsu-b", now, [10.0], [OTHER]),
        )  # fmt: skip
        datagram = Signer("rsu-b", keys["rsu-b"]).encode(genuine)
        raw.send(datagram)
        raw.send(datagram)
        service.run(rx, duration_s=0.4)
    finally:
        raw.close()
        for pub in publishers.values():
            pub.close()
        rx.close()
        service.close()

    records = [json.loads(line) for line in out.read_text().splitlines()]
    fixes = [r for r in records if r["record"] == "fix" and r["emitter"] == f"{EMITTER:016x}"]
    assert fixes and all(f["ok"] for f in fixes), fixes
    last = fixes[-1]
    assert set(last["sensors"]) == {"rsu-a", "rsu-b"}
    err = np.array([last["x_m"], last["y_m"]]) - TARGET
    cov = np.array([[last["cov_xx_m2"], last["cov_xy_m2"]], [last["cov_xy_m2"], last["cov_yy_m2"]]])
    # the reported covariance is the bound for this geometry, and covers the error
    stations_xy = np.array([[p.x_m, p.y_m] for p in STATIONS.values()])
    crb = bearing_crb(stations_xy, TARGET, [SIGMA_DEG, SIGMA_DEG])
    np.testing.assert_allclose(cov, crb, rtol=0.1, atol=0.05)
    assert float(err @ np.linalg.solve(cov, err)) < 13.8  # χ²₂ 99.9 %
    assert np.hypot(*err) < 4 * np.sqrt(np.trace(crb))
    # the forged bearing was not used: no fix near where it points, only one sensor for OTHER
    assert not any(r["record"] == "fix" and r["emitter"] == f"{OTHER:016x}" for r in records)
    stats = next(r for r in records if r["record"] == "stats")
    assert stats["link.rejected.bad_signature"] == 1
    assert stats["link.rejected.replay"] == 1
    assert stats["link.verified"] == 3 * 2 + 1
    assert stats["messages"] == 7 and stats["bearings"] == 7
    assessments = [r for r in records if r["record"] == "assessment"]
    assert assessments and assessments[-1]["advisory"] == "none"  # no vehicle given


def test_service_judges_a_pedestrian_in_the_vehicle_path() -> None:
    now = 1_763_800_030 * S
    # the vehicle state is 1 s old: the service extrapolates it to x = -20 m
    car = VehicleState(x_m=-32.0, y_m=15.0, heading_deg=90.0, speed_mps=12.0, t_ns=now - S)
    service = BackendService(vehicle=car, clock=lambda: now)
    # a standing pedestrian seen for 2 s: the track learns that it does not move
    for k in range(11):
        t = now - (10 - k) * S // 5
        for sid, pose in STATIONS.items():
            service.on_bearings(
                bearing_batch(sid, t, [true_azimuth(pose, TARGET)], [EMITTER]), pose
            )
        service.set_vehicle(None if k < 10 else car)
        (a,) = service.step(t)
    assert a.advisory == "brake" and a.fix_ok and a.p_collision > 0.2, a
    assert (a.x_m, a.y_m) == pytest.approx(tuple(TARGET), abs=1e-6)
    assert service.tracker.tracks[EMITTER].updates == 11
    assert a.distance_to_contact_m == pytest.approx(24.0 - 2.25 - 0.25, abs=1e-6)
    assert service.stats.fixes["ok"] == 11
    # once the car has driven past, the pedestrian is no threat
    service.set_vehicle(VehicleState(x_m=30.0, y_m=15.0, heading_deg=90.0, speed_mps=12.0))
    (b,) = service.step(now + S // 10)
    assert b.advisory == "clear" and b.impact_speed_mps == 0.0
    # parallel lines of bearing: a flagged fix, caution, no position used
    lone = BackendService(vehicle=car, clock=lambda: now)
    for sid, pose in STATIONS.items():
        lone.on_bearings(bearing_batch(sid, now, [0.0], [OTHER]), pose)
    (c,) = lone.step(now)
    assert not c.fix_ok and c.advisory == "caution" and "parallel" in c.reasons[0]
    assert len(lone.tracker) == 0


def test_many_vehicles_judged_at_once_get_what_each_gets_alone() -> None:
    """A backend serving many cars judges all of them in one batch: each car gets what
    it gets alone, and what the service gives when that car is its own vehicle."""
    now = 1_763_800_030 * S
    walkers = {11: np.array([4.0, 15.0]), 12: np.array([-6.0, 22.0]), 13: np.array([9.0, 8.0])}
    service = BackendService(clock=lambda: now)
    for k in range(8):
        t = now - (8 - k) * S // 10
        for sid, pose in STATIONS.items():
            az = [true_azimuth(pose, p + np.array([0.3 * k, 0.0])) for p in walkers.values()]
            # parallel lines of bearing: a flagged fix, never tracked
            service.on_bearings(bearing_batch(sid, t, [*az, 0.0], [*walkers, OTHER]), pose)
        service.step(t)
    assert set(service.fixes) == {11, 12, 13, OTHER} and OTHER not in service.tracker.tracks
    cars = [
        VehicleState(x_m=-12.0, y_m=15.5, heading_deg=90.0, speed_mps=12.0, t_ns=now),
        VehicleState(x_m=-6.0, y_m=-5.0, heading_deg=0.0, speed_mps=9.0, t_ns=now),
        VehicleState(x_m=30.0, y_m=8.0, heading_deg=270.0, speed_mps=3.0, t_ns=now),
    ]
    asked = [[11, 12, OTHER, 999], [12, 13, 11, OTHER], [13]]
    before = sum(service.stats.assessments.values())
    many = service.assess_many(list(zip(cars, asked, strict=True)), now)
    # every pair counted, the untracked emitter's once per car asking
    assert sum(service.stats.assessments.values()) - before == 3 + 4 + 1
    # the untracked emitter's assessment is the same for every car: not located, caution
    (other_0,) = [a for a in many[0] if a.emitter == f"{OTHER:016x}"]
    (other_1,) = [a for a in many[1] if a.emitter == f"{OTHER:016x}"]
    assert other_0 == other_1 and other_0.advisory == "caution"
    assert other_0.reasons[0].startswith("emitter not located")
    assert [sorted(a.emitter for a in got) for got in many] == [
        sorted(f"{e:016x}" for e in ems if e != 999) for ems in asked
    ]
    advice = set()
    for car, emitters, got in zip(cars, asked, many, strict=True):
        alone = service.assess_for(car, emitters, now)
        service.set_vehicle(car)
        own = {a.emitter: a for a in service.step(now)}
        for a, b in zip(got, alone, strict=True):
            assert a.emitter == b.emitter and a.advisory == b.advisory
            close = pytest.approx(b.p_collision, rel=1e-9, abs=1e-15, nan_ok=True)
            assert a.p_collision == close
            assert a.risk == pytest.approx(b.risk, rel=1e-9, abs=1e-15, nan_ok=True)
            c = own[a.emitter]
            assert a.advisory == c.advisory and a.reasons == c.reasons
            assert c.p_collision == close
            advice.add(a.advisory)
    assert {"brake", "caution"} <= advice
    assert service.assess_many([], now) == []


def test_vehicle_state_from_a_file_and_a_udp_feed(tmp_path: Path) -> None:
    path = tmp_path / "vehicle.yaml"
    path.write_text("x_m: -40\ny_m: 0\nheading_deg: 90\nspeed_mps: 10\n")
    assert load_vehicle(path) == VehicleState(-40.0, 0.0, 90.0, 10.0)
    bad = tmp_path / "bad.yaml"
    bad.write_text("x_m: -40\ny_m: 0\nheading_deg: 90\nspeed_mps: 10\nspeed_kmh: 36\n")
    with pytest.raises(ConfigError, match=r"bad\.yaml: unknown key 'speed_kmh'"):
        load_vehicle(bad)
    feed = VehicleFeed.listen("udp://127.0.0.1:0")
    try:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        assert isinstance(feed.transport, UdpTransport)
        addr = feed.transport.address
        sock.sendto(b"not json", addr)
        sock.sendto(b'{"x_m": 1, "y_m": 2}', addr)  # missing heading and speed
        sock.sendto(b'{"x_m": 1, "y_m": 2, "heading_deg": 0, "speed_mps": 3}', addr)
        sock.close()
        state = feed.poll(1.0)
        for _ in range(20):
            if feed.received + sum(feed.rejected.values()) == 3:
                break
            state = feed.poll(0.05)
    finally:
        feed.close()
    assert state == VehicleState(1.0, 2.0, 0.0, 3.0)
    assert feed.rejected == {"not_json": 1, "bad_state": 1}


def test_backend_settings_from_yaml(tmp_path: Path) -> None:
    path = tmp_path / "backend.yaml"
    path.write_text(
        "backend:\n"
        "  association: {window_s: 0.5, epoch_s: 30}\n"
        "  triangulation: {max_range_fraction: 0.08}\n"
        "  encounter: {threat_kind: cyclist, thresholds: {brake_risk: 0.005}}\n"
    )
    cfg = load_backend_config(path)
    assert cfg.association.window_s == 0.5 and cfg.association.epoch_s == 30
    assert cfg.triangulation.max_range_fraction == 0.08
    assert cfg.encounter.threat_kind == "cyclist"
    assert cfg.encounter.thresholds.brake_risk == 0.005
    assert cfg.tracker == BackendConfig().tracker
    typo = tmp_path / "typo.yaml"
    typo.write_text("association: {window: 0.5}\n")
    with pytest.raises(ConfigError, match=r"typo\.yaml.*association.*unknown key 'window'"):
        load_backend_config(typo)
    long = tmp_path / "long.yaml"
    long.write_text("association: {window_s: 90}\n")
    with pytest.raises(ConfigError, match=r"long\.yaml.*shorter than the nonce epoch"):
        load_backend_config(long)
    bad = tmp_path / "bad.yaml"
    bad.write_text("triangulation: {max_condition: 0.5}\n")
    with pytest.raises(ConfigError, match=r"bad\.yaml: triangulation: max_condition must be > 1"):
        load_backend_config(bad)


@pytest.mark.parametrize("n_emitters", [3, 20])
def test_the_service_gives_each_emitter_the_fix_of_its_bearings(n_emitters: int) -> None:
    """A few emitters or many, each one's fix is what its own bearings give."""
    from rfsas_hw.backend.triangulation import triangulate

    rng = np.random.default_rng(n_emitters)
    targets = rng.uniform([-20.0, 5.0], [20.0, 40.0], size=(n_emitters, 2))
    emitters = [EMITTER + i for i in range(n_emitters)]
    service = BackendService()
    t = time.time_ns()
    measured: dict[str, np.ndarray] = {}
    for sid, pose in STATIONS.items():
        az = np.array([true_azimuth(pose, p) for p in targets]) + rng.normal(
            0, SIGMA_DEG, n_emitters
        )
        measured[sid] = az
        service.on_bearings(bearing_batch(sid, t, az.tolist(), emitters), pose)
    service.step(t)
    stations = np.array([[p.x_m, p.y_m] for p in STATIONS.values()])
    for i, emitter in enumerate(emitters):
        fix = service.fixes[emitter]
        az = [measured[sid][i] for sid in STATIONS]
        direct = triangulate(stations, az, [SIGMA_DEG] * 2)
        assert fix.ok == direct.ok
        assert np.allclose([fix.x_m, fix.y_m], direct.position, atol=1e-6)
