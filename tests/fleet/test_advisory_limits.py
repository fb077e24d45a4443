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
