"""Waypoint motion and traffic models."""

from __future__ import annotations

import numpy as np
import pytest

from rfsas_hw.records import FrameKind
from rfsas_hw.twin.motion import Track
from rfsas_hw.twin.scan import NOT_LISTENING, ScanPlan
from rfsas_hw.twin.scenario import MoverSpec, ScanSpec, TrafficSpec, WaypointSpec
from rfsas_hw.twin.traffic import emitter_transmissions, transmissions


def _mover(**kw) -> MoverSpec:
    wps = (
        WaypointSpec(0, 0, speed_mps=2.0, pause_s=1.0),
        WaypointSpec(10, 0, speed_mps=5.0, pause_s=2.0),
        WaypointSpec(10, 10),
    )
    return MoverSpec(id="m", kind="cyclist", waypoints=wps, **kw)


def test_track_positions_speeds_and_pauses() -> None:
    tr = Track.from_spec(_mover(start_s=0.5))
    # waits 0.5 s + 1 s pause, 5 s to (10, 0), 2 s pause, 2 s to (10, 10)
    assert tr.end_s == pytest.approx(10.5)
    np.testing.assert_allclose(
        tr.position([0.0, 1.5, 4.0, 6.5, 7.5, 9.5, 20.0]),
        [[0, 0], [0, 0], [5, 0], [10, 0], [10, 0], [10, 5], [10, 10]],
    )
    np.testing.assert_allclose(tr.speed_mps([1.0, 3.0, 7.0, 9.0, 12.0]), [0, 2, 0, 5, 0])
    # heading holds the nearest moving leg: east, then north (compass 90 then 0)
    np.testing.assert_allclose(tr.heading_deg([0.0, 3.0, 7.0, 9.0, 12.0]), [90, 90, 0, 0, 0])


def test_standing_mover() -> None:
    tr = Track.from_spec(MoverSpec(id="s", kind="static", waypoints=(WaypointSpec(3, 4),)))
    np.testing.assert_allclose(tr.position([0, 100]), [[3, 4], [3, 4]])
    np.testing.assert_allclose(tr.velocity([0, 100]), 0)


def test_beacons_every_102_4_ms() -> None:
    tx = transmissions(TrafficSpec(model="beacon", channels=(11,)), 60.0, np.random.default_rng(1))
    gaps = np.diff(tx.t_s)
    assert len(tx) == pytest.approx(60 / 0.1024, abs=2)
    assert np.mean(gaps) == pytest.approx(0.1024, abs=1e-4)
    assert np.all(tx.channel == 11) and np.all(tx.kind == FrameKind.BEACON)
    assert np.all(np.diff(tx.seq) % 4096 == 1)


def test_ble_advertising_interval_plus_delay() -> None:
    spec = TrafficSpec(model="ble-adv", interval_s=0.1, gap_ms=0.4)
    tx = transmissions(spec, 30.0, np.random.default_rng(2))
    events = tx.t_s[tx.channel == 37]
    gaps = np.diff(events)
    # advDelay uniform in [0, 10 ms]: every gap within [interval, interval + 10 ms], mean +5 ms
    assert gaps.min() >= 0.1 - 1e-12 and gaps.max() <= 0.11 + 1e-12
    assert np.mean(gaps) == pytest.approx(0.105, abs=5e-4)
    assert set(np.unique(tx.channel).tolist()) == {37, 38, 39}
    assert np.all(tx.seq == -1)


def test_probe_bursts_sweep_channels() -> None:
    spec = TrafficSpec(
        model="probe-bursts",
        interval_s=2.0,
        jitter_ms=0,
        channels=(1, 6, 11),
        frames_per_channel=2,
        gap_ms=1.0,
        channel_dwell_ms=15.0,
        phase_s=0.5,
    )
    tx = transmissions(spec, 4.0, np.random.default_rng(3))
    assert len(tx) == 12
    np.testing.assert_allclose(tx.t_s[:6], [0.5, 0.501, 0.515, 0.516, 0.53, 0.531])
    assert tx.channel[:6].tolist() == [1, 1, 6, 6, 11, 11]


def test_several_models_merge_in_time() -> None:
    specs = (TrafficSpec(model="beacon"), TrafficSpec(model="data-bursts", burst_frames=3))
    tx = emitter_transmissions(specs, 5.0, np.random.default_rng(4))
    assert np.all(np.diff(tx.t_s) >= 0)
    assert {int(k) for k in tx.kind} == {FrameKind.BEACON, FrameKind.QOS_DATA}


def test_scan_plan_channels_and_switch_time() -> None:
    plan = ScanPlan.from_spec(ScanSpec(channels=(1, 6, 11), dwell_ms=100, switch_ms=5))
    assert plan.period_s == pytest.approx(0.3)
    got = plan.channel_at([0.001, 0.01, 0.101, 0.15, 0.25, 0.31]).tolist()
    assert got == [NOT_LISTENING, 1, NOT_LISTENING, 6, 11, 1]
    fixed = ScanPlan((6,), 0.1, 0.0)
    assert np.all(fixed.channel_at(np.linspace(0, 5, 50)) == 6)
