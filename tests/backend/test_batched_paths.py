"""The backend's batched computations on random inputs: rows are independent, and a
batch of one is what a single call gives."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rfsas_hw.backend.encounter import (
    EncounterConfig,
    assess_encounter,
    assess_encounters,
    assess_pairs,
)
from rfsas_hw.backend.risk import AdvisoryThresholds
from rfsas_hw.backend.tracking import Track, predict_tracks
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.errors import BackendError

S = 1_000_000_000


def _random_threats(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """States around a vehicle near the origin; some standing, covariances of many sizes."""
    states = np.column_stack([rng.uniform(-40, 40, (n, 2)), rng.normal(0, 2.0, (n, 2))])
    states[::6, 2:] = 0.0  # standing: heading taken as north
    states[1::9, 2:] = 0.1  # below the moving speed
    a = rng.normal(size=(n, 4, 4))
    covs = a @ a.transpose(0, 2, 1) * rng.uniform(0.01, 4.0, (n, 1, 1))
    return states, covs


@pytest.mark.parametrize("seed", range(6))
def test_a_threat_judged_alone_is_its_row_of_the_batch(seed: int) -> None:
    """Rows are independent: each threat alone gets what it gets among 59 others."""
    rng = np.random.default_rng(seed)
    cfg = EncounterConfig(
        threat_kind=("pedestrian", "cyclist", "vehicle")[seed % 3],
        reaction_s=float(rng.uniform(0, 1)),
        horizon_s=float(rng.uniform(2, 10)),
        thresholds=AdvisoryThresholds(stop_margin=float(rng.uniform(1, 3))),
    )
    n = 60
    advisories = set()
    for _ in range(5):
        vehicle = VehicleState(
            float(rng.uniform(-30, 30)),
            float(rng.uniform(-30, 30)),
            float(rng.uniform(0, 360)),
            float(rng.choice([0.0, rng.uniform(0, 18)])),
        )
        states, covs = _random_threats(rng, n)
        ok = (rng.random(n) < 0.8).tolist()
        why = [f"reason {i}" for i in range(n)]
        alarm = bool(rng.random() < 0.3)
        batch = assess_encounters(
            vehicle, states, covs, cfg, fix_ok=ok, fix_reason=why, link_alarm=alarm
        )
        assert len(batch) == n
        for i, got in enumerate(batch):
            ref = assess_encounter(
                vehicle,
                states[i],
                covs[i],
                cfg,
                fix_ok=bool(ok[i]),
                fix_reason=why[i],
                link_alarm=alarm,
            )
            assert got.advisory is ref.advisory, i
            advisories.add(got.advisory)
            assert got.p_collision == pytest.approx(ref.p_collision, rel=1e-9, abs=1e-14)
            for name in ("t_closest_s", "impact_speed_mps", "fatality_risk", "stopping_distance_m"):
                assert getattr(got, name) == pytest.approx(getattr(ref, name), rel=1e-12, abs=1e-12)
            assert got.risk == pytest.approx(ref.risk, rel=1e-9, abs=1e-14)
            if math.isinf(ref.distance_to_contact_m):
                assert math.isinf(got.distance_to_contact_m)
            else:
                assert got.distance_to_contact_m == pytest.approx(ref.distance_to_contact_m)
            if ref.p_collision > 1e-9:  # below, the printed numbers are round-off
                assert got.reasons == ref.reasons
    assert len(advisories) >= 2


def test_batched_encounters_refuse_bad_rows() -> None:
    car = VehicleState(0.0, 0.0, 90.0, 10.0)
    states = np.zeros((3, 4))
    covs = np.broadcast_to(np.eye(4), (3, 4, 4)).copy()
    states[1, 2] = np.nan
    with pytest.raises(BackendError, match="threat 1"):
        assess_encounters(car, states, covs)
    bad_cov = covs.copy()
    bad_cov[2, 3, 1] = np.inf  # a velocity covariance entry of the last row
    with pytest.raises(BackendError, match="threat 2"):
        assess_encounters(car, np.zeros((3, 4)), bad_cov)
    with pytest.raises(BackendError, match="shape"):
        assess_encounters(car, np.zeros((3, 3)), covs)
    with pytest.raises(BackendError, match="one entry per threat"):
        assess_encounters(car, np.zeros((3, 4)), covs, fix_ok=[True])
    assert assess_encounters(car, np.zeros((0, 4)), np.zeros((0, 4, 4))) == []


def test_a_track_predicted_alone_is_its_row_of_the_batch() -> None:
    rng = np.random.default_rng(7)
    now = 1_000 * S
    tracks = []
    for k in range(40):
        a = rng.normal(size=(4, 4))
        tracks.append(
            Track(k, rng.normal(0, 10, 4), a @ a.T, now - int(rng.uniform(-0.5, 3) * S), 1, ())
        )
    states, covs = predict_tracks(tracks, now, 1.5)
    for i, track in enumerate(tracks):
        x, p = track.predict(now, 1.5)
        np.testing.assert_allclose(states[i], x, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(covs[i], p, rtol=1e-12, atol=1e-12)
    empty_states, empty_covs = predict_tracks([], now, 1.0)
    assert empty_states.shape == (0, 4) and empty_covs.shape == (0, 4, 4)


def test_stacked_filter_updates_equal_one_after_the_other() -> None:
    from rfsas_hw.backend.tracking import Tracker, TrackerConfig

    rng = np.random.default_rng(21)
    cfg = TrackerConfig(accel_sigma_mps2=1.5)
    one, many = Tracker(cfg), Tracker(cfg)
    emitters = [int(e) for e in rng.integers(1, 2**62, 40)]
    t = 1_000 * S
    for step in range(12):
        t += int(rng.uniform(0.05, 0.5) * S)
        chosen = [e for e in emitters if rng.random() < 0.7]
        times = [t - int(rng.uniform(0, 0.3) * S) for _ in chosen]
        if step == 6:
            times[0] -= 100 * S  # out of order
        pos = rng.normal(0, 20, (len(chosen), 2)) + step * 1.3
        pos[::5] += 200.0  # outside the gate: restarts
        a = rng.normal(size=(len(chosen), 2, 2))
        cov = a @ a.transpose(0, 2, 1) + 0.1 * np.eye(2)
        sensors = [("a", "b")] * len(chosen)
        for i, e in enumerate(chosen):
            one.update(e, times[i], pos[i], cov[i], sensors[i])
        many.update_many(chosen, times, pos, cov, sensors)
    assert one.stats == many.stats and one.stats.restarted > 0 and one.stats.out_of_order > 0
    assert one.tracks.keys() == many.tracks.keys()
    for e, track in one.tracks.items():
        other = many.tracks[e]
        assert (track.t_ns, track.updates, track.sensors) == (
            other.t_ns,
            other.updates,
            other.sensors,
        )
        np.testing.assert_allclose(other.state, track.state, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(other.cov, track.cov, rtol=1e-9, atol=1e-12)
    with pytest.raises(BackendError, match="not a finite"):
        many.update_many(
            [1, 2],
            [t, t],
            np.array([[0.0, 0.0], [np.nan, 0.0]]),
            np.eye(2)[None].repeat(2, 0),
            [(), ()],
        )


@pytest.mark.parametrize("seed", range(4))
def test_a_pair_judged_among_many_vehicles_is_what_its_vehicle_alone_gets(seed: int) -> None:
    """Many vehicles in one call: each (vehicle, threat) pair gets what the threat gets
    judged alone against its own vehicle, whatever the other vehicles are."""
    rng = np.random.default_rng(100 + seed)
    cfg = EncounterConfig(
        threat_kind=("pedestrian", "cyclist", "vehicle")[seed % 3],
        reaction_s=float(rng.uniform(0, 1)),
        thresholds=AdvisoryThresholds(brake_min_fixes=3, brake_needs_path=seed % 2 == 0),
    )
    vehicles = [
        VehicleState(
            float(rng.uniform(-30, 30)),
            float(rng.uniform(-30, 30)),
            float(rng.uniform(0, 360)),
            float(rng.choice([0.0, rng.uniform(0, 18)])),
            length_m=float(rng.uniform(3, 12)),
            width_m=float(rng.uniform(1.5, 2.6)),
            sigma_along_m=float(rng.uniform(0.5, 4)),
        )
        for _ in range(7)
    ]
    n = 80
    states, covs = _random_threats(rng, n)
    owner = rng.integers(0, len(vehicles), n)
    ok = (rng.random(n) < 0.8).tolist()
    why = [f"reason {i}" for i in range(n)]
    fixes = rng.integers(1, 6, n).tolist()
    batch = assess_pairs(
        vehicles, owner, states, covs, cfg, fix_ok=ok, fix_reason=why, track_fixes=fixes
    )
    assert len(batch) == n
    advisories = set()
    for i, got in enumerate(batch):
        ref = assess_encounter(
            vehicles[owner[i]],
            states[i],
            covs[i],
            cfg,
            fix_ok=bool(ok[i]),
            fix_reason=why[i],
            track_fixes=fixes[i],
        )
        advisories.add(got.advisory)
        assert got.advisory is ref.advisory, i
        assert got.p_collision == pytest.approx(ref.p_collision, rel=1e-9, abs=1e-14)
        assert got.stopping_distance_m == pytest.approx(ref.stopping_distance_m, rel=1e-12)
        for name in ("t_closest_s", "impact_speed_mps", "risk"):
            assert getattr(got, name) == pytest.approx(getattr(ref, name), rel=1e-9, abs=1e-14)
        if ref.p_collision > 1e-9:
            assert got.reasons == ref.reasons
    assert len(advisories) >= 2
    # the vehicles differ enough that a pair judged against another vehicle would differ
    other = assess_pairs(vehicles, (owner + 1) % len(vehicles), states, covs, cfg)
    assert [a.p_collision for a in other] != [a.p_collision for a in batch]


def test_pairs_refuse_a_vehicle_index_outside_the_vehicles() -> None:
    car = VehicleState(0.0, 0.0, 90.0, 10.0)
    covs = np.broadcast_to(np.eye(4), (2, 4, 4)).copy()
    with pytest.raises(BackendError, match="index the 1 vehicle"):
        assess_pairs([car], [0, 1], np.zeros((2, 4)), covs)
    with pytest.raises(BackendError, match="one entry per threat"):
        assess_pairs([car], [0], np.zeros((2, 4)), covs)
    assert assess_pairs([], [], np.zeros((0, 4)), np.zeros((0, 4, 4))) == []
