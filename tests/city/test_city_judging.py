"""What a district backend leaves out of its judging, and what it still sends: the service
stepping without judging its own (absent) vehicle, the reach rule (an emitter a vehicle
cannot meet within the encounter model's horizon is not judged against it), and the
all-clear a vehicle is owed after a BRAKE or CAUTION."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from cryptography.hazmat.primitives.asymmetric import ec

from rfsas_hw.backend.risk import ADVISORY_RANK
from rfsas_hw.backend.service import BackendConfig, BackendService
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.city.backendproc import (
    Reach,
    VehicleStates,
    fresh_first,
    nothing_due,
    tick_phase_s,
)
from rfsas_hw.errors import BackendError
from rfsas_hw.fleet.advisory import AdvisorySink, decode_advisory
from rfsas_hw.fleet.advisory_limits import AdvisoryLimiter, AdvisoryLimits
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.link.signing import Signer
from rfsas_hw.link.topics import Route, TopicRouter
from rfsas_hw.records import emitter_hex
from tests.city.servicehelp import walk_east

S = 1_000_000_000
NOW = 1_800_000_000 * S


def test_a_step_without_assessing_keeps_the_fixes_and_tracks_and_predicts_the_same() -> None:
    judging, quiet = BackendService(clock=lambda: NOW), BackendService(clock=lambda: NOW)
    for service in (judging, quiet):
        walk_east(service, 7, 0.0, 15.0, 8, NOW)
        walk_east(service, 9, 200.0, 15.0, 3, NOW)
    assessed = judging.step(NOW)
    assert quiet.step(NOW, assess=False) == []
    assert quiet.assessments == {}
    assert quiet.fixes == judging.fixes
    assert quiet.tracker.tracks.keys() == judging.tracker.tracks.keys()
    ids, states = quiet.predicted(NOW)
    assert sorted(ids.tolist()) == sorted(judging.assessments) == [7, 9]
    for e, row in zip(ids.tolist(), states.tolist(), strict=True):
        a = judging.assessments[e]
        assert row == pytest.approx([a.x_m, a.y_m, a.vx_mps, a.vy_mps], rel=1e-12, abs=1e-9)
    assert {a.advisory for a in assessed} == {"none"}  # no vehicle: nothing judged
    empty = BackendService(clock=lambda: NOW)
    assert empty.predicted(NOW)[1].shape == (0, 4)


def _cars(speeds: list[float], xs: list[float]) -> VehicleStates:
    n = len(speeds)
    return VehicleStates(
        t_ns=NOW,
        ids=tuple(f"car-{i}" for i in range(n)),
        x_m=np.array(xs, float),
        y_m=np.zeros(n),
        heading_deg=np.full(n, 90.0),
        speed_mps=np.array(speeds, float),
        length_m=np.full(n, 4.5),
        width_m=np.full(n, 1.8),
    )


def test_an_emitter_out_of_a_vehicles_reach_is_not_judged_unless_it_owes_a_clear() -> None:
    # emitters at x = 40 (walking 1 m/s), 40 (speed unknown), 80 (beyond near_m)
    emitters = np.array([1, 2, 3], np.uint64)
    ex, ey = np.array([40.0, 40.0, 80.0]), np.zeros(3)
    speed = np.array([1.0, math.nan, 1.0])
    # a standing car and one at 5 m/s, both at x = 0: reach 0 + 10 + 15 = 25 m and 75 m
    cars = _cars([0.0, 5.0], [0.0, 0.0])
    close, judged = cars.within(emitters, ex, ey, 60.0, Reach(10.0, 15.0, speed))
    assert close.tolist() == [[True, True, False], [True, True, False]]
    assert judged.tolist() == [[False, True, False], [True, True, False]]
    # the standing car was last told more than clear about emitter 1: it is judged
    owed = {"car-0": {emitter_hex(1), emitter_hex(3)}, "gone": {emitter_hex(2)}}
    _, judged = cars.within(emitters, ex, ey, 60.0, Reach(10.0, 15.0, speed, owed))
    assert judged.tolist() == [[True, True, False], [True, True, False]]
    # without the rule every emitter within near_m is judged
    assert cars.within(emitters, ex, ey, 60.0)[1].tolist() == close.tolist()
    # a margin that covers the gap judges the standing car too
    _, wide = cars.within(emitters, ex, ey, 60.0, Reach(10.0, 31.0, speed))
    assert wide[0].tolist() == [True, True, False]


def test_the_limiter_knows_which_emitters_a_vehicle_was_last_told_more_than_clear() -> None:
    limiter = AdvisoryLimiter(AdvisoryLimits(min_interval_s=0.5, memory=2))

    class Item:
        def __init__(self, emitter: str, advisory: str) -> None:
            self.emitter, self.advisory, self.p_collision = emitter, advisory, 0.5

    limiter.select([Item("a", "brake"), Item("b", "caution"), Item("c", "clear")], 0.0)
    assert limiter.unsettled == {"b"}  # "a" forgotten (memory 2): nothing remembered owes
    limiter.select([Item("b", "brake"), Item("d", "caution")], 1.0)
    assert limiter.unsettled == {"b", "d"}
    limiter.select([Item("b", "clear")], 2.0)
    assert limiter.unsettled == {"d"}


class _Sent:
    def __init__(self) -> None:
        self.items: list[tuple[str, str]] = []

    def publish(self, route: Route, datagram: bytes) -> None:
        self.items += [(it.emitter, it.advisory) for it in decode_advisory(datagram).items]


def test_a_vehicle_told_to_brake_still_gets_its_clear_once_out_of_reach() -> None:
    service = BackendService(clock=lambda: NOW)
    walk_east(service, 7, 0.0, 15.0, 8, NOW)
    ids, states = service.predicted(NOW)
    sent = _Sent()
    sink = AdvisorySink(
        Signer("be-1", ec.generate_private_key(ec.SECP256R1())),
        sent,
        TopicRouter(SiteOrigin(52.43, 13.53)),
        "0" * 16,
        vehicle_id="car-0",
        clock=lambda: NOW,
        monotonic=lambda: 0.0,
        tile_topics=False,
    )
    standing = _cars([0.0], [float(states[0, 0])])
    standing = replace(standing, y_m=np.array([float(states[0, 1]) - 40.0]))
    car = VehicleState(x_m=0.0, y_m=0.0, heading_deg=0.0, speed_mps=0.0, t_ns=NOW)
    told = [replace(a, advisory="brake") for a in service.assess_for(car, [7], NOW)]
    sink.on_results([], told)
    assert sent.items == [(emitter_hex(7), "brake")]

    def rule() -> Reach:
        speed = np.hypot(states[:, 2], states[:, 3])
        return Reach(10.0, 15.0, speed, {"car-0": sink.limiter.unsettled})

    # 40 m away, standing, the emitter walking 2 m/s: out of reach (35 m), but owed its clear
    close, judged = standing.within(ids, states[:, 0], states[:, 1], 60.0, rule())
    assert close.all() and judged.all()
    ((_, vehicle, mine),) = standing.near(ids, judged, NOW)
    assessed = service.assess_many([(vehicle, mine)], NOW)[0]
    assert [a.advisory for a in assessed] == ["clear"]
    sink.monotonic = lambda: 1.0
    sink.on_results([], assessed)
    assert sent.items[-1] == (emitter_hex(7), "clear")
    # told: from now on the pair is out of reach
    _, judged = standing.within(ids, states[:, 0], states[:, 1], 60.0, rule())
    assert not judged.any()


def test_the_vehicles_near_a_new_fix_are_judged_and_advised_first() -> None:
    car = VehicleState(x_m=0.0, y_m=0.0, heading_deg=0.0, speed_mps=10.0)
    near = [(0, car, [1, 2]), (1, car, [3]), (2, car, [2, 4]), (3, car, [5])]
    first, rest = fresh_first(near, {4: 10, 1: 20})
    assert [i for i, _, _ in first] == [0, 2]  # near emitter 1 or 4, in their order
    assert [i for i, _, _ in rest] == [1, 3]
    assert fresh_first(near, {}) == [near]  # no fix in this step: one batch
    assert fresh_first(near, {9: 1}) == [near]  # none near a new fix
    assert fresh_first([], {1: 1}) == []


def test_the_backends_ticks_are_spread_over_the_slots_of_a_step() -> None:
    phases = [tick_phase_s(k, 2, 0.1) for k in range(2)]
    assert phases == pytest.approx([0.005, 0.045])  # 2 slots of 20 ms apart
    five = [tick_phase_s(k, 5, 0.1) for k in range(5)]
    assert five == pytest.approx([0.005, 0.025, 0.045, 0.065, 0.085])
    # every phase just after a slot's end, within the step
    for phase in phases + five + [tick_phase_s(k, 7, 0.1) for k in range(7)]:
        assert 0 < phase < 0.1
        assert math.isclose((phase - 0.005) / 0.02, round((phase - 0.005) / 0.02), abs_tol=1e-9)
    with pytest.raises(ValueError, match="index"):
        tick_phase_s(2, 2, 0.1)


def test_a_vehicle_near_only_untracked_emitters_told_recently_would_be_sent_nothing() -> None:
    """Skipping a vehicle when ``nothing_due`` says so never changes what goes out: over
    random steps of untracked (CAUTION for every vehicle) and tracked emitters, whenever
    it says nothing is due the limiter's own choice is empty, with riding along on."""
    rng = np.random.default_rng(3)

    class Item:
        def __init__(self, emitter: int, advisory: str) -> None:
            self.emitter, self.advisory, self.p_collision = emitter_hex(emitter), advisory, 0.1

    limiter = AdvisoryLimiter(
        AdvisoryLimits(min_interval_s=1.0, ride_along_s=0.25, brake_interval_s=0.5)
    )
    caution = ADVISORY_RANK["caution"]
    said_nothing = 0
    for step in range(400):
        now = step * 0.1
        near = sorted({int(e) for e in rng.integers(1, 9, size=rng.integers(1, 5))})
        tracked = {e for e in near if e > 6}  # 7 and 8 are tracked: any advice
        items = [
            Item(e, str(rng.choice(["clear", "caution", "brake"])) if e in tracked else "caution")
            for e in near
        ]
        skip = nothing_due(limiter, now, near, tracked, caution)
        chosen = limiter.select(items, now)
        if skip:
            said_nothing += 1
            assert chosen == []
    assert said_nothing > 50  # the case arises often enough to be tested
    assert not nothing_due(limiter, 1e6, [1], set(), caution)  # an interval later: due
    assert not nothing_due(limiter, 0.0, [99], set(), caution)  # never told: due


@pytest.mark.parametrize("overlap_s", [None, 2.0])
def test_an_earlier_epochs_emitters_are_dropped_once_the_overlap_is_over(
    overlap_s: float | None,
) -> None:
    """Ids are keyed per nonce epoch: with ``epoch_overlap_s``, an emitter last fixed in
    the epoch before is kept that long into the new one (its successor's id takes over)
    and then dropped, fix and track; without it, after ``drop_after_s`` (10 s)."""
    base = BackendConfig()
    config = replace(base, tracker=replace(base.tracker, epoch_overlap_s=overlap_s))
    service = BackendService(config, clock=lambda: NOW)
    epoch_ns = int(config.association.epoch_s * S)
    walk_east(service, 7, 0.0, 15.0, 8, NOW - S)  # fixed until 1.1 s before the epoch
    walk_east(service, 8, 0.0, -15.0, 8, NOW + S)  # another, fixed in the new epoch
    assert 7 in service.fixes and 7 in service.tracker.tracks
    service.step(NOW + 1_900_000_000)  # 1.9 s into the epoch: both kept
    assert {7, 8} <= set(service.fixes)
    service.step(NOW + 2 * S)  # the overlap is over
    assert (7 in service.fixes, 7 in service.tracker.tracks) == (overlap_s is None,) * 2
    assert 8 in service.fixes and 8 in service.tracker.tracks  # of this epoch: kept
    service.step(NOW + epoch_ns // 2)  # half an epoch on, silent for 30 s: both gone
    assert not service.fixes
    with pytest.raises(BackendError, match="epoch_overlap_s"):
        replace(base.tracker, epoch_overlap_s=0.0)
