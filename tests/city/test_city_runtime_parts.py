"""The runtime's own parts without SUMO: tile plan and worker split, the deployment's clock,
a backend judging another vehicle than its own, advisories on the vehicle's topic only,
the gateway's broker grants, and the vehicles' gateway handing messages to their vehicles."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import pytest
from cryptography.hazmat.primitives.asymmetric import ec

from rfsas_hw.backend.service import BackendService
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.city.backendproc import VehicleStates
from rfsas_hw.city.clock import SimClock
from rfsas_hw.city.partition import plan_tiles, split_units
from rfsas_hw.city.vehicles import (
    KnownBackends,
    VehicleGateway,
    arrival_rows,
    arrivals_of,
    most_severe,
)
from rfsas_hw.errors import ConfigError
from rfsas_hw.fleet.advisory import AdvisorySink, decode_advisory
from rfsas_hw.fleet.broker import Identity, acl_lines
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.link.signing import Signer
from rfsas_hw.link.topics import Route, TopicRouter
from rfsas_hw.link.transport import Transport
from tests.city.servicehelp import walk_east

S = 1_000_000_000


@dataclass(frozen=True)
class Site:
    id: str
    x_m: float
    y_m: float
    junction: str
    tile: str


def test_a_junction_in_two_tiles_goes_to_one_backend_and_every_tile_has_one_owner() -> None:
    units = [
        Site("a0", 0, 0, "J1", "t1"),
        Site("a1", 10, 0, "J1", "t2"),  # the same junction across a tile edge
        Site("b0", 500, 0, "J2", "t3"),
        Site("b1", 510, 0, "J2", "t3"),
        Site("c0", 1000, 0, "J3", "t4"),
    ]
    tiles = {t: (x, 0.0) for t, x in (("t1", 0), ("t2", 10), ("t3", 505), ("t4", 1000))}
    tiles["t5"] = (990.0, 50.0)  # no units: goes with the nearest tile that has some
    tiles = {"1" * 15 + k[-1]: v for k, v in tiles.items()}
    units = [Site(u.id, u.x_m, u.y_m, u.junction, "1" * 15 + u.tile[-1]) for u in units]
    plan = plan_tiles(units, ["be-1", "be-2"], tiles)
    owner = {t: g.name for g in plan.groups.values() for t in g.tiles}
    assert sorted(owner) == sorted(tiles)
    assert owner["1" * 15 + "1"] == owner["1" * 15 + "2"]
    assert owner["1" * 15 + "5"] == owner["1" * 15 + "4"]
    assert set(owner.values()) == {"be-1", "be-2"}
    with pytest.raises(ConfigError):
        plan_tiles([], ["be-1"], tiles)


def test_workers_get_whole_junctions() -> None:
    units = [Site(f"u{j}{k}", j * 100.0, 0.0, f"J{j}", "t") for j in range(5) for k in range(2)]
    parts = split_units(units, 2)
    assert len(parts) == 2 and sum(len(p) for p in parts) == 10
    for p in parts:
        junctions = {u.junction for u in p}
        for j in junctions:
            assert sum(u.junction == j for u in p) == 2
    assert len(split_units(units[:2], 4)) == 1
    with pytest.raises(ConfigError):
        split_units(units, 0)


def test_sim_clock_runs_at_its_scale() -> None:
    wall = SimClock(time.time_ns())
    assert abs(wall() - time.time_ns()) < 50_000_000
    anchor = time.time_ns() - 10 * S
    slow = SimClock(anchor, 0.5)
    ahead = (time.time_ns() - anchor) / S
    assert 4.5 < (slow() - anchor) / S < 0.5 * ahead + 1.0
    assert slow.wall_s(1.0) == 2.0
    with pytest.raises(ValueError):
        SimClock(0, 0.0)


def _fixed_service(now_ns: int) -> BackendService:
    """A service with one tracked emitter (7) at (0, 15) walking east."""
    service = BackendService(clock=lambda: now_ns)
    walk_east(service, 7, 0.0, 15.0, 8, now_ns)
    return service


def test_assess_for_judges_another_vehicle_as_the_service_judges_its_own() -> None:
    now = 1_800_000_000 * S
    car = VehicleState(x_m=1.0, y_m=-10.0, heading_deg=0.0, speed_mps=12.0, t_ns=now)
    far = VehicleState(x_m=300.0, y_m=300.0, heading_deg=90.0, speed_mps=12.0, t_ns=now)
    service = _fixed_service(now)
    assert 7 in service.fixes
    mine = service.assess_for(car, [7, 12345], now)
    assert [a.emitter for a in mine] == [f"{7:016x}"]
    service.set_vehicle(car)
    own = service.step(now)
    assert own[0].advisory == mine[0].advisory
    assert own[0].p_collision == pytest.approx(mine[0].p_collision, rel=1e-9)
    assert service.assess_for(far, [7], now)[0].advisory != "brake"
    assert service.assess_for(car, [], now) == []


def test_the_cars_near_emitters_are_those_within_reach_moved_to_now() -> None:
    rng = np.random.default_rng(5)
    n = 40
    states = VehicleStates(
        t_ns=10 * S,
        ids=tuple(f"car-{i}" for i in range(n)),
        x_m=rng.uniform(-300, 300, n),
        y_m=rng.uniform(-300, 300, n),
        heading_deg=rng.uniform(-10, 370, n),
        speed_mps=rng.uniform(0, 15, n),
        length_m=np.full(n, 4.5),
        width_m=np.full(n, 1.8),
    )
    emitters = np.arange(100, 160, dtype=np.uint64)
    ex, ey = rng.uniform(-300, 300, 60), rng.uniform(-300, 300, 60)
    close, judged = states.within(emitters, ex, ey, 60.0)
    assert judged is close
    near = states.near(emitters, judged, 10 * S + S // 2)
    want = {}
    for i in range(n):
        d = np.hypot(ex - states.x_m[i], ey - states.y_m[i])
        if (d < 60.0).any():
            want[i] = sorted(int(e) for e in emitters[d < 60.0])
    assert 5 < len(want) < n
    assert [i for i, _, _ in near] == sorted(want)
    for i, car, close in near:
        assert sorted(close) == want[i]
        a = np.radians(states.heading_deg[i])
        half_s = 0.5 * states.speed_mps[i]
        assert car.x_m == pytest.approx(states.x_m[i] + np.sin(a) * half_s, abs=1e-9)
        assert car.y_m == pytest.approx(states.y_m[i] + np.cos(a) * half_s, abs=1e-9)
        assert 0 <= car.heading_deg < 360 and car.t_ns == 10 * S + S // 2
    _, none = states.within(emitters[:0], ex[:0], ey[:0], 60.0)
    assert states.near(emitters[:0], none, 10 * S) == []


class _Topics:
    def __init__(self) -> None:
        self.routes: list[str] = []

    def publish(self, route: Route, datagram: bytes) -> None:
        self.routes.append(route.topic)


def test_an_advisory_sink_can_publish_on_the_vehicle_topic_only() -> None:
    now = 1_800_000_000 * S
    car = VehicleState(x_m=1.0, y_m=-10.0, heading_deg=0.0, speed_mps=12.0, t_ns=now)
    judged = _fixed_service(now).assess_for(car, [7], now)
    router = TopicRouter(SiteOrigin(52.43, 13.53))
    key = ec.generate_private_key(ec.SECP256R1())
    for tiles, want in ((True, 2), (False, 1)):
        out = _Topics()
        sink = AdvisorySink(
            Signer("be-1", key), out, router, "0" * 16, vehicle_id="car-7", tile_topics=tiles
        )
        sink.on_results([], judged)
        assert len(out.routes) == want
        assert out.routes[-1] == "rfsas/v1/vehicle/car-7/advisory"


def test_the_gateway_reads_every_vehicle_topic_and_writes_nothing() -> None:
    lines = acl_lines(Identity("vehicles", "gateway"))
    assert "topic read rfsas/v1/vehicle/+/advisory" in lines
    assert not any(ln.startswith("topic write") for ln in lines)
    assert "topic read rfsas/v1/vehicle/car-7/advisory" in acl_lines(Identity("car-7", "vehicle"))


class _Collect:
    def __init__(self) -> None:
        self.datagrams: list[bytes] = []

    def publish(self, route: Route, datagram: bytes) -> None:
        self.datagrams.append(datagram)


class _Queue(Transport):
    def __init__(self, items: list[bytes]) -> None:
        self.items = items

    def send(self, datagram: bytes) -> None:
        raise AssertionError("the gateway never sends")

    def recv(self, timeout: float | None = None) -> bytes | None:
        return self.items.pop(0) if self.items else None

    def close(self) -> None:
        pass


class _Keys:
    def __init__(self, key: ec.EllipticCurvePublicKey) -> None:
        self.key = key

    def backend_key(self, backend_id: str) -> ec.EllipticCurvePublicKey | None:
        return self.key if backend_id == "be-1" else None


def test_the_gateway_hands_each_advisory_to_its_own_vehicle() -> None:
    now = time.time_ns()
    car = VehicleState(x_m=1.0, y_m=-10.0, heading_deg=0.0, speed_mps=12.0, t_ns=now)
    judged = _fixed_service(now).assess_for(car, [7], now)
    key = ec.generate_private_key(ec.SECP256R1())
    sent = _Collect()
    router = TopicRouter(SiteOrigin(52.43, 13.53))
    for vid in ("car-1", "car-2", "gone-9"):
        sink = AdvisorySink(
            Signer("be-1", key), sent, router, "0" * 16, vehicle_id=vid, tile_topics=False
        )
        sink.on_results([], judged)
    datagrams = [*sent.datagrams, b"RF\x01garbage"]
    gateway = VehicleGateway(_Keys(key.public_key()), _Queue(datagrams))
    gateway.vehicles(["car-1", "car-2"])
    got = gateway.receive(0)
    assert sorted(a.vehicle_id for a in got) == ["car-1", "car-2"]
    # what the simulator uses of each message, taken from the message itself
    sent_to = {m.vehicle_id: m for m in map(decode_advisory, sent.datagrams)}
    for a in got:
        msg = sent_to[a.vehicle_id]
        assert (a.backend_id, a.seq) == (msg.sender_id, msg.seq)
        assert a.advice == most_severe(msg)
        assert a.emitters == tuple(it.emitter for it in msg.items) and a.emitters
    totals = gateway.totals()
    assert totals.unknown_vehicle == 1
    assert sum(totals.rejected.values()) == 1
    gateway.vehicles(["car-2"])
    assert list(gateway.receivers) == ["car-2"]


def test_the_gateway_process_verifies_with_keys_given_as_der_and_its_arrivals_cross_a_pipe() -> (
    None
):
    import pickle

    from cryptography.hazmat.primitives import serialization

    now = time.time_ns()
    car = VehicleState(x_m=1.0, y_m=-10.0, heading_deg=0.0, speed_mps=12.0, t_ns=now)
    judged = _fixed_service(now).assess_for(car, [7], now)
    key, other = ec.generate_private_key(ec.SECP256R1()), ec.generate_private_key(ec.SECP256R1())
    sent = _Collect()
    router = TopicRouter(SiteOrigin(52.43, 13.53))
    for backend, signing in (("be-1", key), ("be-2", other)):
        sink = AdvisorySink(
            Signer(backend, signing), sent, router, "0" * 16, vehicle_id="car-1", tile_topics=False
        )
        sink.on_results([], judged)
    der = key.public_key().public_bytes(
        serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo
    )
    # be-2 is enrolled with be-1's key: its advisory must not verify
    gateway = VehicleGateway(KnownBackends({"be-1": der, "be-2": der}), _Queue(sent.datagrams))
    gateway.vehicles(["car-1"])
    got = gateway.receive(0)
    assert [a.backend_id for a in got] == ["be-1"]
    assert gateway.totals().rejected["bad_signature"] == 1
    assert arrivals_of(pickle.loads(pickle.dumps(arrival_rows(got)))) == got


def test_a_unit_hears_the_phones_near_any_unit_of_its_junction() -> None:
    from rfsas_hw.bridges.config import UnitSpec
    from rfsas_hw.city.tileworker import _reach
    from rfsas_hw.twin.scenario import PoseSpec

    units = (
        UnitSpec(id="a", pose=PoseSpec(0.0, 0.0, 0.0)),
        UnitSpec(id="b", pose=PoseSpec(30.0, 40.0, 180.0)),
        UnitSpec(id="c", pose=PoseSpec(500.0, 0.0, 90.0)),
    )
    reach = _reach(units, (("a", "b"), ("c",)), 150.0)
    # a phone 150 m from b is at most 200 m from a; c's junction is c alone
    assert reach == {"a": 200.0, "b": 200.0, "c": 150.0}
