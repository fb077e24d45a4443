"""Tracks fed by each unit's bearing (``tracking: bearings``) on fixed cases."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from backendhelp import one_bearing

from rfsas_hw.backend.association import AssociationConfig
from rfsas_hw.backend.bearing_tracking import BearingUpdateConfig, bearing_update
from rfsas_hw.backend.service import BackendConfig, BackendService, load_backend_config
from rfsas_hw.backend.tracking import Tracker
from rfsas_hw.backend.triangulation import TriangulationOptions, triangulate_batch
from rfsas_hw.bridges.config import BACKEND_PROFILES
from rfsas_hw.errors import BackendError, ConfigError
from rfsas_hw.records import BearingBatch, Pose

S = 1_000_000_000
EMITTER = 5
RSU = (4.0, 7.0)


def _batch(sensor: str, t_ns: int, azimuth_deg: float, sigma_deg: float) -> BearingBatch:
    return one_bearing(sensor, t_ns, azimuth_deg, sigma_deg, EMITTER)


def _azimuth_deg(frm: np.ndarray, to: np.ndarray) -> float:
    d = to - frm
    return math.degrees(math.atan2(d[0], d[1]))


def _service(tracking: str, bearings: BearingUpdateConfig | None = None) -> BackendService:
    # the NCAP profile's association window and acceptance limit: long ellipses pass
    return BackendService(
        BackendConfig(
            association=AssociationConfig(window_s=0.5),
            triangulation=TriangulationOptions(max_range_fraction=0.3),
            tracking=tracking,  # type: ignore[arg-type]
            bearings=bearings or BearingUpdateConfig(),
        )
    )


def _approach(
    tracking: str,
    rng: np.random.Generator,
    target: np.ndarray,
    velocity: np.ndarray,
    steps: int,
    bearings: BearingUpdateConfig | None = None,
) -> BackendService:
    """A unit on a car driving east at 16.7 m/s along y = 0 from x = −60 m and a roadside
    unit at (4, 7) m see the emitter every 0.1 s with 6° (one sigma)."""
    svc = _service(tracking, bearings)
    for k in range(steps):
        t = k * S // 10
        where = target + velocity * k * 0.1
        car = np.array([-60.0 + 16.7 * k * 0.1, 0.0])
        for sensor, pos in (("rsu", np.array(RSU)), ("car", car)):
            az = _azimuth_deg(pos, where) + 6.0 * rng.standard_normal()
            svc.on_bearings(_batch(sensor, t, az, 6.0), Pose(float(pos[0]), float(pos[1]), 90.0))
        svc.step(t + 1)
    return svc


def test_a_standing_person_is_tracked_without_the_fix_selections_drift() -> None:
    # a person standing 3 m right of the car's path, the car closing from 60 m to 6 m:
    # the fix-fed track keeps only fixes that err away from the roadside unit while the
    # ellipses are long, and drifts towards the lane (north); fed by bearings it drifts
    # far less: what is left is the start's (the first fix is itself one that passed),
    # and a start with twice the fix's sigma leaves the bearings to correct it
    target, still = np.array([0.0, -3.0]), np.zeros(2)
    runs = 150
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for key, mode, scale in (
        ("fixes", "fixes", 1.0),
        ("bearings", "bearings", 1.0),
        ("wide start", "bearings", 2.0),
    ):
        rng = np.random.default_rng(24)
        err, vel = [], []
        cfg = BearingUpdateConfig(start_sigma_scale=scale)
        for _ in range(runs):
            svc = _approach(mode, rng, target, still, 33, cfg)
            track = svc.tracker.tracks[EMITTER]
            err.append(track.position - target)
            vel.append(track.velocity)
        out[key] = np.array(err), np.array(vel)
    drift = {k: float(v[:, 1].mean()) for k, (_, v) in out.items()}
    assert drift["fixes"] > 0.8  # measured 1.1 m/s
    assert drift["bearings"] < drift["fixes"] / 2.5  # measured 0.34 m/s
    # the wide start: unbiased within 3 standard errors of the mean (150 runs) + 0.1
    for sample in out["wide start"]:
        mean, se = sample.mean(axis=0), sample.std(axis=0) / math.sqrt(runs)
        assert np.all(np.abs(mean) < 3 * se + 0.1), (mean, se)
    # positions unbiased in both bearings-fed modes, spread below a metre per axis
    for key in ("bearings", "wide start"):
        err = out[key][0]
        assert np.all(np.abs(err.mean(axis=0)) < 3 * err.std(axis=0) / math.sqrt(runs) + 0.1)
        assert np.all(np.sqrt(np.mean(err**2, axis=0)) < 1.0)


def test_a_crossing_persons_velocity_is_recovered() -> None:
    # a child walking north across the car's path at 1.4 m/s from 4 m outside it, 3 s
    # (it is in the lane, the car 10 m away)
    v_true = np.array([0.0, 1.4])
    runs = 100
    rms: dict[str, float] = {}
    for mode in ("fixes", "bearings"):
        rng = np.random.default_rng(7)
        err = []
        for _ in range(runs):
            svc = _approach(mode, rng, np.array([0.0, -4.0]), v_true, 30)
            err.append(svc.tracker.tracks[EMITTER].velocity - v_true)
        e = np.array(err)
        rms[mode] = float(np.sqrt(np.mean(e[:, 1] ** 2)))
        if mode == "bearings":
            # unbiased within 3 standard errors of the mean (100 runs)
            assert np.all(np.abs(e.mean(axis=0)) < 3 * e.std(axis=0) / math.sqrt(runs) + 0.1)
    assert rms["bearings"] < 1.0
    assert rms["bearings"] < rms["fixes"] / 1.5


def test_a_bearing_updates_the_track_along_its_line_only() -> None:
    # a static unit due south of a track at (0, 10) m, measuring 1° east of it
    state = np.array([0.0, 10.0, 0.0, 0.0])
    cov = np.diag([4.0, 4.0, 1.0, 1.0])
    out = bearing_update(state, cov, (0.0, 0.0), 1.0, 1.0, BearingUpdateConfig())
    assert out.applied
    assert out.state[0] > 0.05  # moved east, across the line of sight
    assert out.state[1] == pytest.approx(10.0, abs=1e-12)  # not along it
    # iterated: the same step across, re-linearised on the arc of constant range
    more = bearing_update(state, cov, (0.0, 0.0), 1.0, 1.0, BearingUpdateConfig(iterations=3))
    # the iterations change the step across by a few per cent at most here
    assert more.state[0] == pytest.approx(out.state[0], rel=0.05)
    assert more.state[1] == pytest.approx(10.0, abs=0.01)
    assert out.cov[0, 0] < 1.0 and out.cov[1, 1] == pytest.approx(4.0, rel=1e-3)
    np.testing.assert_allclose(out.cov, out.cov.T)
    assert np.all(np.linalg.eigvalsh(out.cov) > 0)
    # the sensor's position sigma widens the measurement: a smaller step
    wide = bearing_update(
        state, cov, (0.0, 0.0), 1.0, 1.0, BearingUpdateConfig(station_sigma_m=1.0)
    )
    assert 0 < wide.state[0] < out.state[0]
    with pytest.raises(BackendError, match="positive sigma"):
        bearing_update(state, cov, (0.0, 0.0), 1.0, 0.0, BearingUpdateConfig())


def test_innovation_gate_skips_and_counts_then_a_lost_track_restarts_from_a_fix() -> None:
    state = np.array([0.0, 10.0, 0.0, 0.0])
    cov = np.diag([1.0, 1.0, 1.0, 1.0])
    cfg = BearingUpdateConfig(gate_sigmas=3.0)
    # predicted sigma: √((1 m / 10 m)² + (2°)²) ≈ 6.1°: 25° is outside the gate, 10° inside
    far = bearing_update(state, cov, (0.0, 0.0), 25.0, 2.0, cfg)
    assert not far.applied and far.innovation_sigmas > 3.0
    np.testing.assert_array_equal(far.state, state)
    assert bearing_update(state, cov, (0.0, 0.0), 10.0, 2.0, cfg).applied
    # in the service: one unit's bearings off by 40° are skipped, the track stays
    svc = BackendService(
        BackendConfig(tracking="bearings", bearings=BearingUpdateConfig(lost_after=3))
    )
    units = {"a": np.array([-10.0, 0.0]), "b": np.array([10.0, 0.0])}

    def see(k: int, where: np.ndarray, off_a_deg: float) -> None:
        t = k * S // 10
        for sensor, pos in units.items():
            az = _azimuth_deg(pos, where) + (off_a_deg if sensor == "a" else 0.0)
            svc.on_bearings(_batch(sensor, t, az, 1.0), Pose(float(pos[0]), float(pos[1]), 0))
        svc.step(t + 1)

    for k in range(3):
        see(k, np.array([0.0, 10.0]), 0.0)
    for k in range(3, 8):
        see(k, np.array([0.0, 10.0]), 40.0)
    stats = svc.all_stats()
    assert stats["tracking.gated"] == 5 and stats["tracking.lost"] == 0
    np.testing.assert_allclose(svc.tracker.tracks[EMITTER].position, [0.0, 10.0], atol=1e-6)
    # the emitter is suddenly 16 m away (another device under a reused id): every bearing
    # is gated, the track is lost after 3 and the next fix starts a new one there
    for k in range(8, 11):
        see(k, np.array([5.0, 25.0]), 0.0)
    stats = svc.all_stats()
    assert stats["tracking.lost"] == 1 and stats["tracking.started"] == 2
    assert stats["tracking.gated"] == 5 + 3
    np.testing.assert_allclose(svc.tracker.tracks[EMITTER].position, [5.0, 25.0], atol=1e-6)


def test_bearings_older_than_the_track_are_counted_not_applied() -> None:
    svc = BackendService(BackendConfig(tracking="bearings"))
    target = np.array([0.0, 10.0])
    units = {"a": np.array([-10.0, 0.0]), "b": np.array([10.0, 0.0])}
    for k in range(3):
        for sensor, pos in units.items():
            az = _azimuth_deg(pos, target)
            svc.on_bearings(_batch(sensor, k * S, az, 1.0), Pose(float(pos[0]), float(pos[1]), 0))
        svc.step(k * S + 1)
    late = _azimuth_deg(units["a"], target)
    # a third unit's bearing of 1.8 s arrives after the track took those of 2 s
    svc.on_bearings(_batch("c", 2 * S - S // 5, late, 1.0), Pose(-10.0, 0.0, 0))
    svc.step(2 * S + S // 2)
    assert svc.all_stats()["tracking.out_of_order"] == 1
    # a bearing without a finite azimuth is counted and skipped, the step goes on
    svc.on_bearings(_batch("a", 3 * S, math.nan, 1.0), Pose(-10.0, 0.0, 0))
    svc.step(3 * S + 1)
    assert svc.all_stats()["tracking.invalid"] == 1
    assert svc.tracker.tracks[EMITTER].updates == 3


def test_default_mode_is_fix_fed_everywhere() -> None:
    assert BackendConfig().tracking == "fixes"
    # every bridge profile but the one that names it (the Euro NCAP matrix's)
    bearings = {name for name, p in BACKEND_PROFILES.items() if p.tracking != "fixes"}
    assert bearings == {"urban-intersection-bearings"}
    # the default service's track is the tracker's own over the same fixes
    rng = np.random.default_rng(3)
    svc = _approach("fixes", rng, np.array([0.0, -3.0]), np.zeros(2), 1)
    assert svc.bearing_tracker is None
    assert not any(k.startswith("tracking.") for k in svc.all_stats())
    rng = np.random.default_rng(11)
    svc = _service("fixes")
    ref = Tracker(svc.config.tracker)
    target = np.array([0.0, -3.0])
    for k in range(30):
        t = k * S // 10
        car = np.array([-40.0 + 16.7 * k * 0.1, 0.0])
        stations = np.array([RSU, car])
        az = np.array([_azimuth_deg(p, target) for p in stations]) + rng.normal(0, 3.0, 2)
        for sensor, pos, a in zip(("car", "rsu"), (car, np.array(RSU)), az[::-1], strict=True):
            svc.on_bearings(_batch(sensor, t, float(a), 3.0), Pose(float(pos[0]), float(pos[1]), 0))
        svc.step(t + 1)
        fix = triangulate_batch(
            np.array([car, RSU])[None],
            az[::-1][None],
            np.full((1, 2), 3.0),
            svc.config.triangulation,
        )
        if int(fix.status[0]) == 0:
            ref.update(EMITTER, t, fix.position[0], fix.covariance[0])
    got = svc.tracker.tracks[EMITTER]
    want = ref.tracks[EMITTER]
    assert got.updates == want.updates > 5
    np.testing.assert_allclose(got.state, want.state, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(got.cov, want.cov, rtol=1e-9, atol=1e-12)


def test_tracking_mode_from_a_file(tmp_path: Path) -> None:
    good = tmp_path / "backend.yaml"
    good.write_text(
        "tracking: bearings\n"
        "bearings: {gate_sigmas: 4.0, station_sigma_m: 0.5, fov_deg: [-58, 57.5]}\n"
    )
    cfg = load_backend_config(good)
    assert cfg.tracking == "bearings" and cfg.bearings.gate_sigmas == 4.0
    assert cfg.bearings.station_sigma_m == 0.5 and cfg.bearings.fov_deg == (-58.0, 57.5)
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text("tracking: bearings\nbearings: {fov_deg: [20, 57.5]}\n")
    with pytest.raises(ConfigError, match=r"wrong\.yaml.*fov_deg"):
        load_backend_config(wrong)
    bad = tmp_path / "bad.yaml"
    bad.write_text("tracking: kalman\n")
    with pytest.raises(ConfigError, match="tracking"):
        load_backend_config(bad)
    worse = tmp_path / "worse.yaml"
    worse.write_text("tracking: bearings\nbearings: {iterations: 0}\n")
    with pytest.raises(ConfigError, match="iterations"):
        load_backend_config(worse)


def test_bearings_from_outside_a_units_field_of_view_are_counted_not_applied() -> None:
    # units "a" and "c" look north (0°), unit "b" east (90°): the emitter at (0, 10) m is
    # 45° off a's and c's boresight and 135° off b's; with a 60° field of view b's
    # bearings enter neither the fixes nor the track
    cfg = BackendConfig(tracking="bearings", bearings=BearingUpdateConfig(max_off_boresight_deg=60))
    svc = BackendService(cfg)
    target = np.array([0.0, 10.0])
    units = {
        "a": (np.array([-10.0, 0.0]), 0.0),
        "b": (np.array([10.0, 0.0]), 90.0),
        "c": (np.array([10.0, 0.0]), 0.0),
    }
    for k in range(4):
        for sensor, (pos, heading) in units.items():
            az = _azimuth_deg(pos, target)
            pose = Pose(float(pos[0]), float(pos[1]), heading)
            svc.on_bearings(_batch(sensor, k * S // 10, az, 1.0), pose)
        svc.step(k * S // 10 + 1)
    stats = svc.all_stats()
    assert stats["tracking.started"] == 1 and stats["fixes.ok"] == 4
    assert svc.fixes[EMITTER].sensors == ("a", "c")
    assert stats["tracking.fix_off_boresight"] == 4  # one per fix
    assert stats["tracking.off_boresight"] == 3 and stats["tracking.applied"] == 6
    assert svc.tracker.tracks[EMITTER].sensors == ("a", "c")
    # b and a alone: no fix, so no track either
    only = BackendService(cfg)
    for sensor in ("a", "b"):
        pos, heading = units[sensor]
        pose = Pose(float(pos[0]), float(pos[1]), heading)
        only.on_bearings(_batch(sensor, 0, _azimuth_deg(pos, target), 1.0), pose)
    only.step(1)
    assert not only.fixes and not only.tracker.tracks
    assert only.all_stats()["tracking.fix_off_boresight"] == 1
    with pytest.raises(BackendError, match="max_off_boresight_deg"):
        BearingUpdateConfig(max_off_boresight_deg=0)
    with pytest.raises(BackendError, match="start_sigma_scale"):
        BearingUpdateConfig(start_sigma_scale=0.5)


def _folded(azimuth_deg: float, heading_deg: float) -> float:
    """A two-antenna unit's front/back ambiguity: a direction θ off boresight is reported
    at 180° − θ off it, on the same side."""
    off = (azimuth_deg - heading_deg + 180.0) % 360.0 - 180.0
    return heading_deg + math.copysign(180.0, off) - off


def _pass_behind(limit_deg: float) -> BackendService:
    """The car's unit (boresight east) drives past a person standing at (0, −2.25) m at
    10 m/s, the roadside unit at (4, 7) m looks at 200°; 1° bearings, no noise. While
    the person is ahead (car at x = −20 … −2 m, at most 49° off boresight) both see
    them; then, with the car at x = 2 m, the person is 132° off the car's boresight
    and its unit reports them folded to 48° off."""
    cfg = BackendConfig(
        association=AssociationConfig(window_s=0.5),
        triangulation=TriangulationOptions(max_range_fraction=0.3),
        tracking="bearings",
        bearings=BearingUpdateConfig(max_off_boresight_deg=limit_deg),
    )
    svc = BackendService(cfg)
    person = np.array([0.0, -2.25])
    rsu = np.array(RSU)
    for k in [*range(19), 22]:
        t = k * S // 10
        car = np.array([-20.0 + 1.0 * k, 0.0])
        az = _azimuth_deg(car, person)
        if k == 22:
            az = _folded(az, 90.0)
            assert abs(az - 90.0) < 50.0  # the measured direction is in view
        svc.on_bearings(_batch("car", t, az, 1.0), Pose(float(car[0]), 0.0, 90.0))
        svc.on_bearings(_batch("rsu", t, _azimuth_deg(rsu, person), 1.0), Pose(4.0, 7.0, 200.0))
        svc.step(t + 1)
        if k < 19:  # in view: every step's bearings make an accepted fix
            fix = svc.fixes[EMITTER]
            assert fix.t_ns == t and fix.ok and fix.sensors == ("car", "rsu")
    return svc


def test_a_bearing_folded_into_the_front_is_left_out_by_the_tracks_direction() -> None:
    svc = _pass_behind(60.0)
    stats = svc.all_stats()
    assert stats["tracking.started"] == 1
    # the folded bearing is left out of the fix by the track's predicted direction (the
    # measured one is in view): with the roadside unit's alone there is no fix this
    # step, and the track does not take it either
    assert stats["tracking.fix_off_boresight"] == 1
    assert stats["tracking.off_boresight"] == 1 and stats["tracking.gated"] == 0
    assert svc.fixes[EMITTER].t_ns == 18 * S // 10
    np.testing.assert_allclose(svc.tracker.tracks[EMITTER].position, [0.0, -2.25], atol=1e-3)
    # without the limit the folded bearing makes a fix, far from the person
    wide = _pass_behind(180.0)
    fix = wide.fixes[EMITTER]
    assert fix.t_ns == 22 * S // 10 and fix.sensors == ("car", "rsu")
    assert math.hypot(fix.x_m - 0.0, fix.y_m + 2.25) > 1.0
    assert wide.all_stats()["tracking.fix_off_boresight"] == 0


def test_censored_reading_is_the_truncated_normal() -> None:
    from scipy.stats import truncnorm

    from rfsas_hw.backend.bearing_tracking import censored_reading

    lo, hi, s = -0.77, 0.76, 0.08  # radians: a −44° … 43.5° window, 4.6° sigma
    for u in (0.0, 0.5, 0.72, 0.8, 1.2, -0.75, -2.0):
        shift, factor = censored_reading(u, s * s, lo, hi)
        mean, var = truncnorm.stats((lo - u) / s, (hi - u) / s, loc=u, scale=s, moments="mv")
        assert shift == pytest.approx(float(mean) - u, rel=1e-6, abs=1e-12)
        assert factor == pytest.approx(float(var) / s**2, rel=1e-6, abs=1e-9)
    # far outside the window: the edge, a variance near 0, and finite numbers
    shift, factor = censored_reading(40.0, s * s, lo, hi)
    assert 40.0 + shift == pytest.approx(hi, abs=s / 10) and 0 < factor < 1e-3
    shift, factor = censored_reading(-40.0, s * s, lo, hi)
    assert -40.0 + shift == pytest.approx(lo, abs=s / 10) and 0 < factor < 1e-3
    assert censored_reading(0.0, s * s, lo, hi) == pytest.approx((0.0, 1.0), abs=1e-12)
    with pytest.raises(BackendError, match="lo < hi"):
        censored_reading(0.0, s * s, hi, lo)


def test_readings_censored_at_the_field_of_view_do_not_pull_a_track_to_boresight() -> None:
    # a unit at the origin looking north; a person 47° off its boresight, 10 m away.
    # The unit's edge rule lets a 5° reading through only while reading + 3σ stays
    # inside its 57.5° field of view, so every reading that arrives errs towards
    # boresight (mean about 40°). A track that knows the censoring stays on the person.
    sigma = 5.0
    truth = 47.0
    rng = np.random.default_rng(3)
    readings = truth + sigma * rng.standard_normal(4000)
    passed = readings[readings + 3 * sigma <= 57.5][:60]
    assert len(passed) == 60 and passed.mean() < truth - 5.0

    def track(cfg: BearingUpdateConfig) -> float:
        a = math.radians(truth)
        state = np.array([10 * math.sin(a), 10 * math.cos(a), 0.0, 0.0])
        cov = np.diag([4.0, 4.0, 1e-6, 1e-6])
        applied = 0
        for z in passed:
            out = bearing_update(state, cov, (0.0, 0.0), float(z), sigma, cfg, 0.0)
            applied += out.applied
            state, cov = out.state, out.cov
        assert applied >= 55  # (the gate's 3 σ skips the odd one)
        return math.degrees(math.atan2(state[0], state[1]))

    plain = track(BearingUpdateConfig())
    censored = track(BearingUpdateConfig(fov_deg=(-58.0, 57.5)))
    assert plain < truth - 5.0  # pulled towards boresight by the selection
    assert censored == pytest.approx(truth, abs=2.0)
    # without the boresight the field of view is not applied: the plain update
    a = math.radians(truth)
    state = np.array([10 * math.sin(a), 10 * math.cos(a), 0.0, 0.0])
    cov = np.diag([4.0, 4.0, 1e-6, 1e-6])
    cfg = BearingUpdateConfig(fov_deg=(-58.0, 57.5))
    np.testing.assert_array_equal(
        bearing_update(state, cov, (0.0, 0.0), 40.0, sigma, cfg).state,
        bearing_update(state, cov, (0.0, 0.0), 40.0, sigma, BearingUpdateConfig()).state,
    )
    with pytest.raises(BackendError, match="fov_deg"):
        BearingUpdateConfig(fov_deg=(10.0, 50.0))
    with pytest.raises(BackendError, match="edge_sigmas"):
        BearingUpdateConfig(edge_sigmas=-1.0)


def _bursts(
    readings: str, rng: np.random.Generator, start: np.ndarray, velocity: np.ndarray, steps: int
) -> BackendService:
    """As :func:`_approach`, but every unit reports a burst of three frames per step, 2 ms
    apart, each with its own independent 6° error (as the matrix's units do)."""
    svc = _service("bearings", BearingUpdateConfig(readings=readings))  # type: ignore[arg-type]
    for k in range(steps):
        t = k * S // 10
        car = np.array([-60.0 + 16.7 * k * 0.1, 0.0])
        for sensor, pos in (("rsu", np.array(RSU)), ("car", car)):
            times = [t + i * 2_000_000 for i in range(3)]
            az = [
                _azimuth_deg(pos, start + velocity * ti / S) + 6.0 * rng.standard_normal()
                for ti in times
            ]
            batch = BearingBatch(
                sensor_id=sensor,
                t_ns=np.array(times, np.int64),
                azimuth_deg=np.array(az),
                sigma_deg=np.full(3, 6.0),
                snr_db=np.full(3, 20.0),
                channel=np.full(3, 6, np.int16),
                emitter=np.full(3, EMITTER, np.uint64),
            )
            svc.on_bearings(batch, Pose(float(pos[0]), float(pos[1]), 90.0))
        svc.step(times[-1] + 1)
    return svc


def test_every_reading_of_a_burst_updates_the_track_with_readings_all() -> None:
    # the same bursts: 'newest' applies one bearing per unit and step, 'all' all three;
    # with independent errors the velocity of a crossing child is then better known
    # (√3 if the filter had converged; asked: at least 1.3 times smaller RMS error)
    v_true = np.array([0.0, 1.4])
    err: dict[str, list[np.ndarray]] = {"newest": [], "all": []}
    for run in range(60):
        used = {}
        for readings in ("newest", "all"):
            # the same draws in both: the same fixes, the track starts at the same step
            svc = _bursts(readings, np.random.default_rng(run), np.array([0.0, -4.0]), v_true, 30)
            err[readings].append(svc.tracker.tracks[EMITTER].velocity - v_true)
            assert svc.bearing_tracker is not None
            stats = svc.bearing_tracker.stats
            used[readings] = stats.applied + stats.gated + stats.off_boresight
        assert used["newest"] > 0
        assert used["all"] == 3 * used["newest"]
    rms = {k: float(np.sqrt(np.mean(np.sum(np.array(v) ** 2, axis=1)))) for k, v in err.items()}
    assert rms["all"] < rms["newest"] / 1.3, rms


def test_readings_all_rejects_an_unknown_choice_and_reads_from_a_file(tmp_path: Path) -> None:
    with pytest.raises(BackendError, match="readings"):
        BearingUpdateConfig(readings="some")  # type: ignore[arg-type]
    path = tmp_path / "backend.yaml"
    path.write_text("tracking: bearings\nbearings: {readings: all}\n", encoding="utf-8")
    assert load_backend_config(path).bearings.readings == "all"
    path.write_text("tracking: bearings\nbearings: {readings: every}\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="readings"):
        load_backend_config(path)
