"""What the dashboard keeps: worst advisory, timeline, tracks, ageing, declared sensors."""

from __future__ import annotations

import math

import numpy as np

from rfsas_hw.backend.site import SiteConfig, SiteSensor
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.records import Assessment, BearingBatch, Fix, Pose
from rfsas_hw.web.state import DashboardLimits, DashboardState

NS = 1_000_000_000
T0 = 1_767_268_800 * NS


def fix(emitter: str, t_ns: int, x: float = 1.0) -> Fix:
    return Fix(t_ns, emitter, x, 2.0, 4.0, 0.0, 1.0, True, "ok", "", ("a", "b"), 1.0, 1.0)


def judged(emitter: str, t_ns: int, advisory: str, risk: float, x: float = 1.0) -> Assessment:
    return Assessment(
        t_ns, emitter, x, 2.0, 1.0, 0.0, 1.0, 1.5, 0.0, 0.1, ("a", "b"), True, "",
        0.1, 1.0, 5.0, 10.0, 0.2, risk, advisory, (), False,
    )  # fmt: skip


def test_state_keeps_what_the_page_draws() -> None:
    now = [T0]
    site = SiteConfig(
        origin=SiteOrigin(52.2053, 0.1218, 12.0),
        sensors=(SiteSensor("rsu-a", Pose(-30.0, 10.0, 90.0), 60.0),),
    )
    vehicle = VehicleState(1.75, -50.0, 0.0, 20.0)
    state = DashboardState(
        site,
        clock=lambda: now[0],
        vehicle=lambda: vehicle,
        link_health=lambda: [{"sensor_id": "rsu-a", "state": "ok", "messages": 3, "lost": 0,
                              "p50_ms": 0.51234, "p99_ms": math.nan, "silent_for_s": 0.0}],
        link_stats=lambda: {"verified": 3, "rejected.replay": 1},
        limits=DashboardLimits(bearing_keep_s=1.0, track_points=3, fix_keep_s=2.0),
    )  # fmt: skip
    pushed = []
    state.listeners.append(lambda: pushed.append(state.version))
    snap = state.snapshot()
    assert snap["advisory"] == "none" and snap["fixes"] == []
    assert snap["sensors"] == [
        {"id": "rsu-a", "x_m": -30.0, "y_m": 10.0, "heading_deg": 90.0, "fov_deg": 60.0,
         "heard": False}
    ]  # fmt: skip
    state.on_bearings(
        BearingBatch(
            "rsu-b", np.array([T0], np.int64), np.array([45.0]), np.array([1.0]),
            np.array([20.0]), np.array([6], np.int16), np.array([0xAB], np.uint64),
        ),
        Pose(0.0, -20.0, 0.0),
    )  # fmt: skip
    for k, (advisory, risk) in enumerate([("clear", 1e-4), ("caution", 0.01), ("brake", 0.3)]):
        now[0] = T0 + k * NS // 10
        state.on_results(
            [fix("e1", now[0], x=k)],
            [judged("e1", now[0], advisory, risk, x=k), judged("e2", now[0], "clear", 1e-5)],
        )
    snap = state.snapshot()
    assert pushed == [1, 2, 3] and snap["version"] == 3
    assert snap["advisory"] == "brake" and snap["vehicle"]["advisory"] == "brake"
    assert [p[1:] for p in snap["timeline"]] == [[1e-4, "clear"], [0.01, "caution"], [0.3, "brake"]]
    assert {s["id"]: s["heard"] for s in snap["sensors"]} == {"rsu-a": False, "rsu-b": True}
    assert snap["bearings"][0]["emitter"] == "00000000000000ab"
    (f,) = snap["fixes"]
    assert f["ellipse"]["semi_major_m"] == 4.0 and f["ellipse"]["n_sigma"] == 2.0
    assert f["lat_deg"] > 52.2053 and f["lon_deg"] > 0.1218
    track = next(t for t in snap["tracks"] if t["emitter"] == "e1")
    assert track["points"] == [[0.0, 2.0], [1.0, 2.0], [2.0, 2.0]] and track["advisory"] == "brake"
    assert snap["links"][0]["p50_ms"] == 0.5 and snap["links"][0]["p99_ms"] is None
    assert snap["link_stats"]["rejected.replay"] == 1
    # later: the bearing and the fix age out, a track no longer judged is dropped
    now[0] = T0 + 3 * NS
    state.on_results([], [judged("e2", now[0], "clear", 1e-5)])
    snap = state.snapshot()
    assert snap["bearings"] == [] and snap["fixes"] == []
    assert [t["emitter"] for t in snap["tracks"]] == ["e2"]
    assert snap["advisory"] == "clear"


def test_no_advisory_once_every_link_is_silent() -> None:
    links = [{"sensor_id": "rsu-a", "state": "ok"}, {"sensor_id": "rsu-b", "state": "ok"}]
    state = DashboardState(SiteConfig(), clock=lambda: T0, link_health=lambda: links)
    state.on_results([fix("e1", T0)], [judged("e1", T0, "caution", 0.01)])
    assert state.snapshot()["advisory"] == "caution" and not state.snapshot()["stale"]
    # one link left: the tracks it feeds still count
    links[0] = {"sensor_id": "rsu-a", "state": "silent"}
    state.on_results([], [judged("e1", T0, "caution", 0.01)])
    assert state.snapshot()["advisory"] == "caution"
    # every link silent: the coasting track's CAUTION is not backed by any sensor
    links[1] = {"sensor_id": "rsu-b", "state": "silent"}
    state.on_results([], [judged("e1", T0, "caution", 0.01)])
    snap = state.snapshot()
    assert snap["advisory"] == "none" and snap["stale"]
    # a link is back: so is the advisory
    links[1] = {"sensor_id": "rsu-b", "state": "ok"}
    state.on_results([], [judged("e1", T0, "brake", 0.2)])
    assert state.snapshot()["advisory"] == "brake" and not state.snapshot()["stale"]
