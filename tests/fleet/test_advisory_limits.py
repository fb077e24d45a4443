"""Advisory volume is bounded: per emitter at most once per ``min_interval_s`` unless its
advice gets more severe (then at once), per vehicle at most ``max_per_s`` a second with
the most severe first; a crowd of new emitters no longer makes a backend publish
thousands of advisories a second."""

from __future__ import annotations

import time

import pytest
from cryptography.hazmat.primitives.asymmetric import ec

from rfsas_hw.fleet.advisory import AdvisorySink, decode_advisory
from rfsas_hw.fleet.advisory_limits import AdvisoryLimiter, AdvisoryLimits
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.link import Signer
from rfsas_hw.link.topics import Route, TopicRouter
from rfsas_hw.records import Assessment


def assessment(emitter: int, advisory: str = "caution", p: float = 0.1) -> Assessment:
    return Assessment(
        t_ns=time.time_ns(),
        emitter=f"{emitter:016x}",
        x_m=5.0,
        y_m=5.0,
        cov_xx_m2=1.0,
        cov_xy_m2=0.0,
        cov_yy_m2=1.0,
        vx_mps=0.0,
        vy_mps=0.0,
        age_s=0.1,
        sensors=("rsu-1", "rsu-2"),
        fix_ok=True,
        fix_reason="ok",
        p_collision=p,
        t_closest_s=1.0,
        distance_to_contact_m=4.0,
        impact_speed_mps=3.0,
        fatality_risk=0.01,
        risk=p,
        advisory=advisory,
        reasons=(),
        link_alarm=False,
    )


class Collect:
    def __init__(self) -> None:
        self.published: list[tuple[Route, bytes]] = []

    def publish(self, route: Route, datagram: bytes) -> None:
        self.published.append((route, datagram))


def sink(clock: list[float], **limits: float) -> tuple[AdvisorySink, Collect]:
    link = Collect()
    signer = Signer("be-a", ec.generate_private_key(ec.SECP256R1()))
    router = TopicRouter(SiteOrigin(48.137, 11.575))
    out = AdvisorySink(
        signer,
        link,
        router,
        router.tile_of(0, 0),
        vehicle_id="car-7",
        limits=AdvisoryLimits(**limits),  # type: ignore[arg-type]
        monotonic=lambda: clock[0],
    )
    return out, link


def sent_to_vehicle(link: Collect) -> list[str]:
    return [
        item.emitter
        for route, d in link.published
        if "/vehicle/" in route.topic
        for item in decode_advisory(d).items
    ]


def test_one_emitter_at_most_once_an_interval_unless_it_gets_worse() -> None:
    clock = [100.0]
    out, link = sink(clock, min_interval_s=1.0)
    for step in range(20):  # 2 s of steps at 10 Hz, the advice unchanged
        clock[0] = 100.0 + step * 0.1
        out.on_results([], [assessment(1)])
    assert len(sent_to_vehicle(link)) == 2  # at 0 s and at 1 s
    clock[0] = 102.05
    out.on_results([], [assessment(1, "brake", 0.6)])  # worse: at once
    assert len(sent_to_vehicle(link)) == 3
    assert out.stats.limited == 18


def test_advice_after_a_brake_repeats_at_the_brake_interval() -> None:
    """An unchanged BRAKE repeats every ``brake_interval_s`` (a vehicle holds a BRAKE only
    for a while after the last one it heard), and so does the milder advice after it;
    CAUTION repeats at ``min_interval_s`` as before."""
    clock = [0.0]
    out, link = sink(clock, min_interval_s=1.0, brake_interval_s=0.5)
    times: dict[str, list[float]] = {"1": [], "2": []}
    for step in range(21):  # 2 s at 10 Hz: emitter 1 a BRAKE, emitter 2 a CAUTION
        clock[0] = step * 0.1
        advice = "clear" if step >= 15 else "brake"  # emitter 1 clears at 1.5 s
        before = len(sent_to_vehicle(link))
        out.on_results([], [assessment(1, advice, 0.6), assessment(2, "caution")])
        for emitter in sent_to_vehicle(link)[before:]:
            times[emitter.lstrip("0")].append(round(clock[0], 1))
    assert times["1"] == [0.0, 0.5, 1.0, 1.5]  # BRAKE at 0, 0.5, 1.0; CLEAR at 1.5
    assert times["2"] == [0.0, 1.0, 2.0]
    with pytest.raises(ValueError, match="brake_interval_s"):
        AdvisoryLimits(brake_interval_s=-1.0)
    with pytest.raises(ValueError, match="ride_along_s"):
        AdvisoryLimits(min_interval_s=1.0, brake_interval_s=0.3, ride_along_s=0.4)


def test_a_crowd_of_new_emitters_is_bounded_most_severe_first() -> None:
    clock = [0.0]
    out, link = sink(clock, max_per_s=100.0)
    offered = 0
    for step in range(50):  # 5 s, 400 new emitters a second (40 a step), one brake each
        clock[0] = step * 0.1
        batch = [assessment(step * 1000 + i, "clear", 0.01) for i in range(39)]
        batch.append(assessment(step * 1000 + 999, "brake", 0.9))
        offered += len(batch)
        out.on_results([], batch)
    sent = sent_to_vehicle(link)
    # the budget: a burst of 100, then 100 a second
    assert 100 + 100 * 4.9 - 1 <= len(sent) <= 100 + 100 * 4.9 + 1
    assert out.stats.limited == offered - len(sent)
    braking = {f"{s * 1000 + 999:016x}" for s in range(50)}
    assert braking <= set(sent)  # every brake went out, whatever the crowd


def test_limits_are_checked() -> None:
    with pytest.raises(ValueError, match="max_per_s"):
        AdvisoryLimits(max_per_s=0.5)
    limiter = AdvisoryLimiter(AdvisoryLimits(memory=3))
    assert limiter.limits.min_interval_s == 0.09


def _messages(link: Collect) -> list[set[str]]:
    return [
        {item.emitter for item in decode_advisory(d).items}
        for route, d in link.published
        if "/vehicle/" in route.topic
    ]


def test_repeats_ride_together_and_none_goes_later() -> None:
    """Three emitters first judged 0.1 s apart, the advice unchanged for 3 s: each on its
    own phase makes a message at every third step; riding along, their repeats travel in
    one message per interval, and each emitter still goes out at least once an interval."""
    sent: dict[float, list[set[str]]] = {}
    worst: dict[float, float] = {}
    for ride in (0.0, 0.25):
        clock = [0.0]
        out, link = sink(clock, min_interval_s=0.5, ride_along_s=ride)
        last_out: dict[str, float] = {}
        worst_gap = 0.0
        for step in range(31):
            clock[0] = round(step * 0.1, 9)
            before = len(link.published)
            out.on_results([], [assessment(k) for k in range(min(step + 1, 3))])
            for route, d in link.published[before:]:
                if "/vehicle/" not in route.topic:
                    continue
                for item in decode_advisory(d).items:
                    if item.emitter in last_out:
                        worst_gap = max(worst_gap, clock[0] - last_out[item.emitter])
                    last_out[item.emitter] = clock[0]
        sent[ride] = _messages(link)
        worst[ride] = worst_gap
    assert worst[0.25] <= worst[0.0] <= 0.6 + 1e-9  # an interval, or the step after it
    # apart: 3 new + 3 emitters repeated about every 0.5 s for 3 s, each on its own
    assert len(sent[0.0]) >= 15
    assert all(len(m) == 1 for m in sent[0.0])
    # together: the 3 firsts, then one message per 0.5 s carrying all three
    assert len(sent[0.25]) < len(sent[0.0]) / 2
    assert sum(len(m) == 3 for m in sent[0.25]) >= 5


def test_riders_never_displace_a_due_assessment() -> None:
    clock = [0.0]
    out, link = sink(clock, min_interval_s=0.5, ride_along_s=0.2, max_per_s=4.0)
    out.on_results([], [assessment(k) for k in range(1, 5)])  # the burst of 4
    clock[0] = 0.3
    out.on_results([], [assessment(1), assessment(2), assessment(5, "brake", 0.9)])
    # one token refilled (0.3 s x 4/s, rounded down): the new brake, not a rider
    assert _messages(link)[-1] == {f"{5:016x}"}
    assert out.stats.limited == 2
    with pytest.raises(ValueError, match="ride_along_s"):
        AdvisoryLimits(min_interval_s=0.5, ride_along_s=0.6)
