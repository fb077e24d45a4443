"""The backend's batched paths give what the one-at-a-time reference gives, on random inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rfsas_hw.backend import service as service_module
from rfsas_hw.backend.encounter import EncounterConfig, assess_encounter, assess_encounters
from rfsas_hw.backend.risk import AdvisoryThresholds
from rfsas_hw.backend.service import BackendConfig, BackendService
from rfsas_hw.backend.tracking import Track, predict_tracks
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.errors import BackendError
from rfsas_hw.records import BearingBatch, Pose

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
def test_batched_encounters_equal_the_one_at_a_time_reference(seed: int) -> None:
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
    with pytest.raises(BackendError, match="shape"):
        assess_encounters(car, np.zeros((3, 3)), covs)
    with pytest.raises(BackendError, match="one entry per threat"):
        assess_encounters(car, np.zeros((3, 4)), covs, fix_ok=[True])
    assert assess_encounters(car, np.zeros((0, 4)), np.zeros((0, 4, 4))) == []


def test_batched_prediction_equals_each_track_on_its_own() -> None:
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


def _feed(service: BackendService, rng: np.random.Generator, n: int, t_ns: int) -> None:
    """Bearings of ``n`` walkers from three stations (some nearly parallel, some wild)."""
    stations = {
        "a": Pose(-25.0, -3.0, 45.0),
        "b": Pose(25.0, -3.0, 315.0),
        "c": Pose(0.0, 30.0, 180.0),
    }
    targets = rng.uniform([-20.0, -10.0], [20.0, 25.0], (n, 2))
    emitters = np.arange(1, n + 1, dtype=np.uint64) * np.uint64(0x9E3779B97F4A7C15 % (1 << 63))
    for sid, pose in stations.items():
        d = targets - [pose.x_m, pose.y_m]
        az = (90.0 - np.degrees(np.arctan2(d[:, 1], d[:, 0]))) % 360.0
        az = az + rng.normal(0, 1.5, n)
        az[rng.random(n) < 0.1] = rng.uniform(0, 360)
        service.on_bearings(
            BearingBatch(
                sensor_id=sid,
                t_ns=np.full(n, t_ns, np.int64),
                azimuth_deg=az,
                sigma_deg=np.full(n, 2.0),
                snr_db=np.full(n, 20.0),
                channel=np.full(n, 6, np.int16),
                emitter=emitters,
            ),
            pose,
        )


def test_service_batched_assessment_gives_the_reference_advisories(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Many emitters through the batch path and through the one-by-one path: same judgements."""
    runs = []
    small_batch = service_module.SMALL_ASSESS
    for small in (small_batch, 10**9):
        monkeypatch.setattr(service_module, "SMALL_ASSESS", small)
        rng = np.random.default_rng(5)
        svc = BackendService(BackendConfig())
        out = []
        for k in range(6):
            t = (1_000 + k // 2) * S + (k % 2) * S // 10
            _feed(svc, rng, 30, t)
            svc.set_vehicle(VehicleState(-30.0 + 2 * k, -1.5, 90.0, 12.0, t_ns=t))
            out.append(svc.step(t))
        runs.append(out)
    batched, reference = runs
    seen = set()
    for got_step, ref_step in zip(batched, reference, strict=True):
        # (the order of near-zero risks may differ by round-off)
        by_emitter = {a.emitter: a for a in ref_step}
        assert sorted(by_emitter) == sorted(a.emitter for a in got_step)
        for got in got_step:
            ref = by_emitter[got.emitter]
            assert got.advisory == ref.advisory
            seen.add(got.advisory)
            assert got.x_m == pytest.approx(ref.x_m)
            assert got.vy_mps == pytest.approx(ref.vy_mps, nan_ok=True)
            assert got.p_collision == pytest.approx(
                ref.p_collision, rel=1e-9, abs=1e-14, nan_ok=True
            )
    assert len(batched[-1]) > small_batch
    assert {"brake", "clear"} <= seen or {"caution", "clear"} <= seen


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
