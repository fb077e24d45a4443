"""The district scorer on hand-made cases whose answers are known."""

from __future__ import annotations

import json
import math

import pytest

from rfsas_hw.city.demand import VruRecord
from rfsas_hw.city.latency import LatencyParts
from rfsas_hw.city.net import Crossing
from rfsas_hw.city.scoring import Actors, CityScorer, ScoringConfig
from rfsas_hw.errors import ConfigError

CAR = (4.5, 1.8)
PED = (0.5, 0.5)
BIKE = (1.6, 0.65)


def cars(*rows: tuple[str, float, float, float, float, float]) -> Actors:
    """(id, x, y, speed, heading, route_m) per car."""
    return Actors.of(
        [r[0] for r in rows],
        ["vehicle"] * len(rows),
        [r[1] for r in rows],
        [r[2] for r in rows],
        [r[3] for r in rows],
        [r[4] for r in rows],
        CAR[0],
        CAR[1],
        [r[5] for r in rows],
    )


def vrus(*rows: tuple[str, str, float, float, float, float]) -> Actors:
    """(id, class, x, y, speed, heading) per VRU."""
    size = {"pedestrian": PED, "bicycle": BIKE}
    return Actors.of(
        [r[0] for r in rows],
        [r[1] for r in rows],
        [r[2] for r in rows],
        [r[3] for r in rows],
        [r[4] for r in rows],
        [r[5] for r in rows],
        [size[r[1]][0] for r in rows],
        [size[r[1]][1] for r in rows],
    )


def test_a_vru_standing_in_the_path_is_a_conflict_once_per_encounter() -> None:
    s = CityScorer()
    # the car's front reaches the pedestrian's disc after (12 - 1.35 - 1.15) / 10 = 0.95 s
    for k in range(3):
        s.step(
            0.1 * k,
            cars(("c1", 0.0, 0.0, 10.0, 0.0, 0.0)),
            vrus(
                ("p-path", "pedestrian", 0.0, 12.0 - k, 0.0, 0.0),
                ("p-far", "pedestrian", 0.0, 40.0, 0.0, 0.0),  # ttc 3.7 s
                ("p-side", "pedestrian", 5.0, 12.0, 0.0, 0.0),  # never touches
            ),
        )
    out = s.summary()
    assert out.conflicts_by_class == {"pedestrian": 1}
    # after a gap of more than encounter_gap_s the same pair counts again
    s.step(
        10.0, cars(("c1", 0.0, 0.0, 10.0, 0.0, 0.0)), vrus(("p-path", "pedestrian", 0, 12, 0, 0))
    )
    assert s.summary().conflicts_by_class == {"pedestrian": 2}


def test_the_ttc_threshold_decides() -> None:
    scene = (cars(("c1", 0.0, 0.0, 10.0, 0.0, 0.0)), vrus(("p", "pedestrian", 0.0, 12.0, 0.0, 0.0)))
    tight = CityScorer(cfg=ScoringConfig(ttc_s=0.9))
    tight.step(0.0, *scene)
    assert tight.summary().conflicts == 0
    loose = CityScorer(cfg=ScoringConfig(ttc_s=1.0))
    loose.step(0.0, *scene)
    assert loose.summary().conflicts == 1


def test_a_crossing_cyclist_on_a_collision_course_is_a_conflict() -> None:
    s = CityScorer()
    # the car reaches y = 10 in 1 s; the cyclist coming from the west reaches x = 0 in 1 s
    s.step(
        0.0, cars(("c1", 0.0, 0.0, 10.0, 0.0, 0.0)), vrus(("b", "bicycle", -5.0, 11.0, 5.0, 90.0))
    )
    assert s.summary().conflicts_by_class == {"bicycle": 1}


def test_collisions_are_counted_by_class_once_per_pair() -> None:
    s = CityScorer()
    for t in (0.0, 0.1):
        s.step(
            t,
            cars(("c1", 0.0, 0.0, 0.0, 0.0, 0.0), ("c2", 50.0, 0.0, 0.0, 90.0, 0.0)),
            vrus(
                ("p", "pedestrian", 0.5, 2.3, 0.0, 0.0),  # inside c1's front
                ("b", "bicycle", 52.5, 0.0, 0.0, 0.0),  # touching c2's front
                ("p-near", "pedestrian", 0.0, 2.9, 0.0, 0.0),  # 0.4 m beyond c1's bumper
            ),
        )
    out = s.summary()
    assert out.collisions_by_class == {"pedestrian": 1, "bicycle": 1}


def test_a_brake_with_no_vru_ahead_is_a_nuisance() -> None:
    s = CityScorer()
    s.step(
        0.0,
        cars(
            ("lonely", 0.0, 0.0, 10.0, 0.0, 400.0),
            ("threat", 100.0, 0.0, 10.0, 0.0, 600.0),
        ),
        vrus(("p", "pedestrian", 100.0, 30.0, 0.0, 0.0)),
    )  # ttc 2.5 s for "threat"
    s.advisory(0.0, "lonely", "brake", LatencyParts(0.02, 0.0, 0.0))
    s.advisory(0.5, "lonely", "brake", LatencyParts(0.02, 0.0, 0.0))  # same episode
    s.advisory(0.0, "threat", "brake", LatencyParts(0.02, 0.0, 0.0))
    s.advisory(0.0, "threat", "caution", LatencyParts(0.02, 0.0, 0.0))
    out = s.summary()
    assert out.brake_episodes == 2
    assert out.nuisance_brakes == 1
    assert out.vehicle_km == pytest.approx(1.0)
    assert out.nuisance_per_100_vehicle_km == pytest.approx(100.0)
    assert out.advisories_by_kind == {"brake": 3, "caution": 1}
    (ev,) = s.nuisance_events
    assert ev == (0.0, 0.0, "lonely")


def test_a_conflict_braked_for_is_advised_and_defused_unless_it_collided() -> None:
    s = CityScorer()
    s.advisory(0.0, "c1", "brake", LatencyParts(0.01, 0.0, 0.0))
    s.step(
        0.5,
        cars(("c1", 0.0, 0.0, 10.0, 0.0, 0.0), ("c2", 50.0, 0.0, 10.0, 0.0, 0.0)),
        vrus(
            ("p1", "pedestrian", 0.0, 12.0, 0.0, 0.0),
            ("p2", "pedestrian", 50.0, 12.0, 0.0, 0.0),
        ),
    )
    out = s.summary()
    assert out.conflicts == 2 and out.conflicts_advised == 1 and out.conflicts_defused == 1
    assert sorted(e[3:] for e in s.conflict_events) == [(False, False), (True, True)]


def test_linkability_is_the_longest_stretch_under_one_emitter_id() -> None:
    s = CityScorer()
    # a pedestrian walks north at 1 m/s for 100 s; the epoch (and its emitter id) changes at 60 s
    for t in range(100):
        s.step(float(t), Actors.empty(), vrus(("p", "pedestrian", 0.0, float(t), 1.0, 0.0)))
        s.fix(float(t), "e1" if t < 60 else "e2", "p", 0.3, float(t), 2.0)
    s.fix(50.0, "ghost", None, 5.0, 5.0, 2.0)
    out = s.summary()
    assert out.linkability["persons"] == 1
    assert out.linkability["max_s"] == pytest.approx(59.0)
    assert out.linkability["max_m"] == pytest.approx(59.0)
    assert out.linkability["max_share"] == pytest.approx(59.0 / 99.0)
    assert out.fixes == 101 and out.fixes_ghost == 1


def test_coverage_counts_phone_carriers_that_reach_the_kerb_with_a_fresh_good_fix() -> None:
    crossing = Crossing("c0", "J", (0.0, 0.0), (10.0, 0.0), 4.0, True)
    table = {
        "seen": VruRecord("seen", "pedestrian", True, "phone-active", False, 0.0),
        "unseen": VruRecord("unseen", "pedestrian", True, "phone-active", False, 0.0),
        "vague": VruRecord("vague", "pedestrian", True, "phone-active", False, 0.0),
        "nophone": VruRecord("nophone", "pedestrian", False, None, False, 0.0),
    }
    s = CityScorer([crossing], table)
    for k in range(10):
        y = -10.0 + k  # walking north at 1 m/s: within 3 m of the kerb at k = 7
        s.fix(float(k), "e-seen", "seen", 1.5, y, 2.0)
        s.fix(float(k), "e-vague", "vague", 10.0, y, 9.0)
        s.step(
            float(k),
            Actors.empty(),
            vrus(
                ("seen", "pedestrian", 0.0, y, 1.0, 0.0),
                ("unseen", "pedestrian", 0.0, y, 1.0, 0.0),
                ("vague", "pedestrian", 10.0, y, 1.0, 0.0),
                ("nophone", "pedestrian", 10.0, y, 1.0, 0.0),
            ),
        )
    out = s.summary()
    (c,) = out.crossings
    assert (c.arrivals, c.arrivals_with_phone, c.covered) == (4, 3, 1)
    assert c.share == pytest.approx(1 / 3)
    assert c.error_p50_m == pytest.approx(1.5, abs=0.25)
    assert c.error_mean_m == pytest.approx(1.5)
    assert out.coverage_share == pytest.approx(1 / 3)
    # standing at the kerb is one arrival, not one per step
    s.step(10.0, Actors.empty(), vrus(("seen", "pedestrian", 0.0, -1.0, 0.0, 0.0)))
    assert s.summary().crossings[0].arrivals == 4


def test_latency_percentiles_and_rates() -> None:
    s = CityScorer()
    s.step(0.0, Actors.empty(), Actors.empty())
    for k in range(100):
        # the slowest two were late at their backend's step
        s.advisory(
            0.0,
            "c",
            "clear",
            (LatencyParts(0.004, 0.003, 0.003) if k < 98 else LatencyParts(0.070, 0.004, 0.006)),
        )
    s.messages(500)
    s.step(10.0, Actors.empty(), Actors.empty())
    out = s.summary()
    assert out.latency_n == 100
    assert out.latency_p50_ms == pytest.approx(10.0, abs=0.5)
    assert out.latency_p99_ms == pytest.approx(80.0, abs=0.5)
    assert out.messages_per_s == pytest.approx(50.0)
    assert out.advisories_per_s == pytest.approx(10.0)
    # each part's own percentiles, over the same advisories
    assert out.latency_parts_ms["to_step"]["p50"] == pytest.approx(4.0, abs=0.5)
    assert out.latency_parts_ms["to_step"]["p99"] == pytest.approx(70.0, abs=0.5)
    assert out.latency_parts_ms["judging"]["p99"] == pytest.approx(4.0, abs=0.5)
    assert out.latency_parts_ms["delivery"]["p50"] == pytest.approx(3.0, abs=0.5)
    assert out.latency_parts_ms["delivery"]["p99"] == pytest.approx(6.0, abs=0.5)
    doc = json.loads(out.to_json())
    assert doc["latency_p99_ms"] == pytest.approx(80.0, abs=0.5)
    assert doc["latency_parts_ms"]["to_step"]["p99"] == pytest.approx(70.0, abs=0.5)
    assert doc["nuisance_per_100_vehicle_km"] is None


def test_a_latency_known_after_its_advisory_counts_once() -> None:
    s = CityScorer()
    s.step(0.0, Actors.empty(), Actors.empty())
    s.advisory(0.0, "c", "clear", None)  # its backend had not reported yet
    s.latency(LatencyParts(0.030, 0.005, 0.005))  # the report came at a later step
    s.latency(LatencyParts(math.nan, 0.0, 0.0))
    s.latency(LatencyParts(0.0, 0.0, -0.001))  # clocks disagree: not a latency
    out = s.summary()
    assert out.latency_n == 1
    assert out.latency_p50_ms == pytest.approx(40.0, abs=0.5)
    assert out.advisories_by_kind == {"clear": 1}


def test_bad_input_is_refused() -> None:
    with pytest.raises(ConfigError, match="ttc_s"):
        ScoringConfig(ttc_s=-1.0)
    with pytest.raises(ConfigError, match="x_m has 1 entries"):
        Actors(["a", "b"], ["vehicle"] * 2, *([__import__("numpy").zeros(1)] * 8))
    s = CityScorer()
    s.step(5.0, Actors.empty(), Actors.empty())
    with pytest.raises(ConfigError, match="after one at 5"):
        s.step(4.0, Actors.empty(), Actors.empty())
    assert math.isfinite(s.summary().duration_s)
