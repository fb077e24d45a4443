"""No confident bearing from outside the field of view: the rules, the guard, the check."""

from __future__ import annotations

import numpy as np
import pytest

from rfsas_hw.df import estimate, fit_calibration, load_calibration, save_calibration
from rfsas_hw.df.calfile import calibration_from_mapping, calibration_to_mapping
from rfsas_hw.df.check import CONFIDENT_WRONG_MAX, check_calibration, constant_guess_rms_deg
from rfsas_hw.df.estimate import DfFlag
from rfsas_hw.df.fovguard import PROVE_MOTION_DEG, FovGuard, boresight_levels, fold_drops
from rfsas_hw.df.fovrule import (
    LEVEL_MARGIN_DB,
    fold_drop_db,
    fold_margin_db,
    near_edge,
    weak_against,
)
from rfsas_hw.rf import GaussianBeamPair, ReceiverModel, turntable_sweep
from rfsas_hw.rf.propagation import free_space_path_loss_db
from rfsas_hw.rf.synth import TurntableSamples, rssi_pairs

ANT = GaussianBeamPair(
    squint_deg=20.0, beamwidth_deg=45.0, peak_gain_dbi=3.0, front_to_back_db=25.0
)
RX = ReceiverModel(measurement_floor_db=1.0, step_db=1.0, chain_offsets_db=(0.0, -1.5))
CHANNEL = 6


@pytest.fixture(scope="module")
def cal():  # type: ignore[no-untyped-def]
    sweep = turntable_sweep(np.arange(-90.0, 90.5, 1.0), 20, -50.0, ANT, RX, 2026, CHANNEL)
    return fit_calibration(sweep, "linear")


def _wrap(x: np.ndarray) -> np.ndarray:
    return (x + 180.0) % 360.0 - 180.0


def _confident_wrong_share(angle, sigma, true) -> float:  # type: ignore[no-untyped-def]
    err = _wrap(angle - true)
    return float(np.mean(np.abs(err) > 3.0 * sigma))


def test_near_edge_and_weak_rules() -> None:
    angle = np.array([0.0, 40.0, -40.0, 30.0, np.nan])
    sigma = np.array([3.0, 2.0, 2.0, 6.0, 1.0])
    got = near_edge(angle, sigma, (-45.0, 45.0), 3.0)
    assert got.tolist() == [False, True, True, True, False]
    weak = weak_against(np.array([-60.0, -67.0, np.nan]), np.array([-60.0, -60.0, -60.0]), 6.0)
    assert weak.tolist() == [False, True, False]


def test_weak_rule_judges_one_frame_as_it_judges_an_array() -> None:
    levels = np.array([-60.0, -67.0, np.nan, -50.0])
    refs = np.array([-60.0, -60.0, -60.0, np.inf])  # +inf: an emitter in its warm-up
    whole = weak_against(levels, refs, 6.0)
    one_by_one = [weak_against(float(x), float(r), 6.0) for x, r in zip(levels, refs, strict=True)]
    assert whole.tolist() == one_by_one == [False, True, False, True]


def test_level_curve_is_fitted_and_round_trips(cal, tmp_path) -> None:  # type: ignore[no-untyped-def]
    table = cal.tables[0]
    assert table.level_db is not None
    # inside the FoV the stronger chain stays within a few dB of boresight; at ±90° it
    # is near the back-lobe floor, about 20 dB down (25 dB front-to-back less 2.4 dB)
    inside = np.abs(table.grid_deg) <= 45.0
    assert np.all(np.abs(table.level_db[inside]) < 4.0)
    assert table.level_at(np.array([90.0]))[0] < -15.0
    path = tmp_path / "cal.yaml"
    save_calibration(cal, path)
    back = load_calibration(path)
    np.testing.assert_allclose(back.tables[0].level_db, table.level_db, atol=1e-3)
    # a file that predates the curve loads, with a flat 0 dB level
    doc = calibration_to_mapping(cal)
    del doc["tables"][0]["level_db"]
    old = calibration_from_mapping(doc, "old.yaml")
    assert old.tables[0].level_db is None
    assert old.tables[0].level_at(np.array([30.0]))[0] == 0.0


def test_bad_level_curve_names_the_key(cal) -> None:  # type: ignore[no-untyped-def]
    doc = calibration_to_mapping(cal)
    doc["tables"][0]["level_db"] = doc["tables"][0]["level_db"][:-1]
    with pytest.raises(Exception, match=r"tables\[0\]\.level_db"):
        calibration_from_mapping(doc, "x.yaml")


def test_edge_rule_refuses_bearings_that_reach_past_the_fov(cal) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(3)
    theta = np.repeat(np.arange(-44.0, 45.0, 1.0), 40)
    r = rssi_pairs(theta, -50.0, ANT, RX, rng)
    ch = np.full(len(theta), CHANNEL)
    on = estimate(cal, r[:, 0], r[:, 1], ch)
    off = estimate(cal, r[:, 0], r[:, 1], ch, edge_sigmas=0.0)
    lo, hi = cal.tables[0].fov_deg
    kept = on.valid
    assert np.all(on.angle_deg[kept] - 3 * on.sigma_deg[kept] >= lo - 1e-3)
    assert np.all(on.angle_deg[kept] + 3 * on.sigma_deg[kept] <= hi + 1e-3)
    refused = (on.flags & np.uint8(DfFlag.MAY_BE_OUTSIDE)) != 0
    assert refused.any() and not (off.flags & np.uint8(DfFlag.MAY_BE_OUTSIDE)).any()
    # only bearings near the ends are refused: the middle of the FoV keeps every frame
    assert not refused[np.abs(theta) < 20.0].any()


def _spinning_sensor(seed: int, period_s: float, duration_s: float = 60.0):  # type: ignore[no-untyped-def]
    """Frames of 24 emitters all around a two-antenna sensor spinning in place."""
    rng = np.random.default_rng(seed)
    n_em, rate = 24, 5.0
    azimuth = np.linspace(-180.0, 180.0, n_em, endpoint=False) + rng.uniform(0.0, 15.0, n_em)
    distance = rng.uniform(5.0, 40.0, n_em)
    t = np.arange(0.0, duration_s, 1.0 / rate)
    tt, em = (a.ravel() for a in np.meshgrid(t, np.arange(n_em), indexing="ij"))
    heading = 360.0 * tt / period_s if period_s > 0 else np.zeros_like(tt)
    true = _wrap(azimuth[em] - heading)
    peak = 15.0 - free_space_path_loss_db(distance[em], 2437.0)
    r = rssi_pairs(true, peak, ANT, RX, rng)
    return true, r, em, (tt * 1e9).astype(np.int64)


def test_emitters_all_around_a_spinning_sensor_give_few_confident_wrong(cal) -> None:  # type: ignore[no-untyped-def]
    period = 10.0
    true, r, em, t_ns = _spinning_sensor(5, period)
    ch = np.full(len(true), CHANNEL)
    plain = estimate(cal, r[:, 0], r[:, 1], ch, edge_sigmas=0.0)
    bare = _confident_wrong_share(
        plain.angle_deg[plain.valid], plain.sigma_deg[plain.valid], true[plain.valid]
    )
    assert bare > 0.5  # without the rules most bearings come from outside and are wrong
    guard = FovGuard(warmup_s=period)
    res = guard.apply(cal, estimate(cal, r[:, 0], r[:, 1], ch), r[:, 0], r[:, 1], ch, em, t_ns)
    v = res.valid
    share = _confident_wrong_share(res.angle_deg[v], res.sigma_deg[v], true[v])
    assert share <= CONFIDENT_WRONG_MAX, share
    # and the sensor still works: most frames from inside the FoV after the warm-up keep
    # their bearing (the edge rule costs the outer ~9° at each end)
    front = (np.abs(true) <= 30.0) & (t_ns >= period * 1e9)
    assert np.mean(v[front]) > 0.8
    assert guard.refused > 0 and len(guard) == 24


def test_guard_refuses_an_emitter_walking_behind_the_sensor(cal) -> None:  # type: ignore[no-untyped-def]
    # one emitter walks at 1.4 m/s on a 10 m circle from boresight round to behind a
    # fixed sensor: half a turn (31 m) in 22 s
    rng = np.random.default_rng(8)
    true = np.linspace(0.0, 180.0, 361)
    peak = 15.0 - free_space_path_loss_db(np.full(len(true), 10.0), 2437.0)
    r = rssi_pairs(true, peak, ANT, RX, rng)
    ch = np.full(len(true), CHANNEL)
    t_ns = (np.arange(len(true)) * (22.0 / 360) * 1e9).astype(np.int64)
    res = FovGuard().apply(
        cal, estimate(cal, r[:, 0], r[:, 1], ch), r[:, 0], r[:, 1], ch, np.zeros(len(true)), t_ns
    )
    behind = true >= 60.0
    assert not res.valid[behind].any()
    assert res.valid[true <= 25.0].mean() > 0.9
    v = res.valid
    assert (
        _confident_wrong_share(res.angle_deg[v], res.sigma_deg[v], true[v]) <= CONFIDENT_WRONG_MAX
    )


def test_guard_reference_decays_and_forgets_old_emitters(cal) -> None:  # type: ignore[no-untyped-def]
    guard = FovGuard(margin_db=6.0, decay_db_per_s=1.0, max_emitters=2, smooth_s=0.0)
    levels = np.array([-50.0, -58.0, -58.0])
    t_ns = np.array([0, 1, 5_000_000_000])
    smooth, refs = guard.track(np.array([7, 7, 7]), t_ns, levels)
    # without smoothing the judged level is the frame's; the second frame is judged
    # against −50 dBm; five seconds later the reference has decayed to −55 dBm (the
    # −58 dBm frame in between did not raise it)
    np.testing.assert_array_equal(smooth, levels)
    assert refs[0] == -50.0 and refs[1] == pytest.approx(-50.0)
    assert refs[2] == pytest.approx(-55.0, abs=1e-6)
    guard.track(np.array([8, 9]), np.array([6, 7]) * 1_000_000_000, np.array([-40.0, -40.0]))
    assert len(guard) == 2
    with pytest.raises(ValueError):
        FovGuard(margin_db=0.0)


def test_guard_rides_out_a_fading_dip_but_not_a_turn_away(cal) -> None:  # type: ignore[no-untyped-def]
    guard = FovGuard(smooth_s=0.3)
    t_ns = np.arange(40) * 100_000_000  # 10 frames a second
    levels = np.full(40, -50.0)
    levels[10] = -62.0  # one frame in a 12 dB fade
    levels[25:] = -72.0  # turned away: 22 dB down for good
    smooth, refs = guard.track(np.zeros(40), t_ns, levels)
    weak = weak_against(smooth, refs, guard.margin_db)
    assert not weak[:25].any()
    assert weak[30:].all()


def test_guard_warmup_refuses_a_new_emitter_first(cal) -> None:  # type: ignore[no-untyped-def]
    guard = FovGuard(warmup_s=2.0)
    _, refs = guard.track(np.array([1, 1]), np.array([0, 3_000_000_000]), np.array([-50.0, -50.0]))
    assert refs[0] == np.inf and refs[1] == -50.0


def test_boresight_level_is_nan_without_a_bearing(cal) -> None:  # type: ignore[no-untyped-def]
    res = estimate(cal, np.array([-50.0, np.nan]), np.array([-52.0, -50.0]), np.array([6, 6]))
    levels = boresight_levels(cal, res, np.array([-50.0, np.nan]), np.array([-52.0, -50.0]), [6, 6])
    assert np.isfinite(levels[0]) and np.isnan(levels[1])


def test_check_scores_samples_outside_the_fov(cal) -> None:  # type: ignore[no-untyped-def]
    full = turntable_sweep(np.arange(-179.0, 180.0, 2.0), 30, -50.0, ANT, RX, 17, CHANNEL)
    report = check_calibration(cal, full)
    assert report.samples == len(full.angle_deg)
    assert report.inside_fov < report.samples / 2
    assert report.confident_wrong_share <= CONFIDENT_WRONG_MAX
    assert report.consistent, report.problems()
    assert not report.constant_beats_bearings


def test_check_fails_a_calibration_that_lets_outside_bearings_through(cal) -> None:  # type: ignore[no-untyped-def]
    # a run with the emitter only beside the antennas (50°…70°): nothing brighter in
    # the run to compare with, so the level rule cannot refuse them; the bearings the
    # edge rule lets through are scored, are wrong, and fail the check
    beside = turntable_sweep(np.arange(50.0, 70.0, 1.0), 30, -50.0, ANT, RX, 21, CHANNEL)
    report = check_calibration(cal, beside)
    assert report.inside_fov == 0
    assert report.valid > 0 and report.outside_bearings == report.valid
    assert report.confident_wrong_share > CONFIDENT_WRONG_MAX
    assert not report.consistent
    assert any("confident-wrong" in p for p in report.problems())


def test_check_with_nothing_to_check(cal) -> None:  # type: ignore[no-untyped-def]
    n = 200
    samples = TurntableSamples(
        np.zeros(n), np.full(n, -5.0), np.full(n, -5.0), np.full(n, CHANNEL, np.int16)
    )  # every reading saturated
    report = check_calibration(cal, samples)
    assert report.nothing_to_check and not report.consistent
    assert report.problems() == ["nothing to check: no sample gave a bearing"]


def test_check_warns_on_few_samples_and_constant_guess(cal) -> None:  # type: ignore[no-untyped-def]
    few = turntable_sweep(np.array([0.0, 2.0]), 10, -50.0, ANT, RX, 4, CHANNEL)
    report = check_calibration(cal, few)
    assert report.few_samples
    # every true angle within 2°: answering 1° always beats bearings of σ ≈ 3°
    assert report.constant_beats_bearings and not report.consistent
    assert constant_guess_rms_deg(np.array([170.0, -170.0])) == pytest.approx(10.0)


def test_channel_consistency_marks_a_disagreement() -> None:
    from rfsas_hw.df.fovchannels import ChannelConsistency

    cc = ChannelConsistency(window_s=0.5, k_sigma=3.0, allowance_deg=2.0)
    t = np.array([0, 100, 200, 300, 2_000]) * 1_000_000
    ch = np.array([1, 6, 1, 6, 1])
    angle = np.array([10.0, 11.0, 10.5, 40.0, -30.0])
    sigma = np.full(5, 2.0)
    got = cc.inconsistent(np.zeros(5), t, ch, angle, sigma)
    # 40° on channel 6 against 10.5° on channel 1 0.1 s before: 29.5° > 3·2.8° + 2°;
    # −30° 1.7 s later has nothing recent on another channel to disagree with
    assert got.tolist() == [False, False, False, True, False]


def test_an_emitter_beside_the_antennas_disagrees_across_channels() -> None:  # type: ignore[no-untyped-def]
    # two channels whose antennas differ only outside the field of view: a 25 dB and a
    # 15 dB back lobe fold an emitter at 60–70° onto different angles inside it
    sweeps = []
    for ftb, ch in ((25.0, 1), (15.0, 6)):
        ant = GaussianBeamPair(squint_deg=20.0, beamwidth_deg=45.0, peak_gain_dbi=3.0,
                               front_to_back_db=ftb)  # fmt: skip
        sweeps.append(turntable_sweep(np.arange(-90.0, 90.5, 1.0), 20, -50.0, ant, RX, ch, ch))
    both = TurntableSamples(
        *(np.concatenate([getattr(s, k) for s in sweeps]) for k in
          ("angle_deg", "rssi1_dbm", "rssi2_dbm", "channel"))
    )  # fmt: skip
    two = fit_calibration(both, "linear")
    assert [t.channel for t in two.tables] == [1, 6]
    rng = np.random.default_rng(30)

    def run(true_deg: float) -> float:
        n = 400
        ch = np.where(np.arange(n) % 2 == 0, 1, 6)
        ftb = np.where(ch == 1, 25.0, 15.0)
        r = np.empty((n, 2))
        for c, f in ((1, 25.0), (6, 15.0)):
            ant = GaussianBeamPair(squint_deg=20.0, beamwidth_deg=45.0, peak_gain_dbi=3.0,
                                   front_to_back_db=f)  # fmt: skip
            sel = ftb == f
            r[sel] = rssi_pairs(np.full(int(sel.sum()), true_deg), -50.0, ant, RX, rng)
            del c
        t_ns = (np.arange(n) * 0.05e9).astype(np.int64)
        # the level rule off (no fixed margin, no folds): only the channels can tell
        guard = FovGuard(margin_db=100.0)
        res = guard.apply(two, estimate(two, r[:, 0], r[:, 1], ch), r[:, 0], r[:, 1], ch,
                          np.zeros(n), t_ns, folds=False)  # fmt: skip
        return float(res.valid.mean())

    assert run(10.0) > 0.97  # inside: the two channels agree
    # beside: channel 1 folds 65° onto about 27°, channel 6 onto about 6°
    assert run(65.0) < 0.2


def _fixed_sensor(seed: int, duration_s: float = 120.0):  # type: ignore[no-untyped-def]
    """Frames of 12 static emitters all around a fixed two-antenna sensor and 12 walkers
    that start in front of it and walk out of its field of view (beside or behind it),
    5 frames/s each."""
    rng = np.random.default_rng(seed)
    rate, n_static, n_walk = 5.0, 12, 12
    t = np.arange(0.0, duration_s, 1.0 / rate)
    az = np.linspace(-180.0, 180.0, n_static, endpoint=False) + rng.uniform(0.0, 20.0, n_static)
    dist = rng.uniform(4.0, 30.0, n_static)
    xy_static = np.stack([dist * np.sin(np.radians(az)), dist * np.cos(np.radians(az))], 1)
    # walkers: straight lines at 1.4 m/s from a point in front (within ±15°, 8-25 m
    # away), in any direction, for 30 s from a random start
    mid = rng.uniform(8.0, 25.0, n_walk)[:, None] * np.stack(
        [np.sin(a := np.radians(rng.uniform(-15, 15, n_walk))), np.cos(a)], 1
    )
    heading = np.radians(rng.uniform(0.0, 360.0, n_walk))
    v = 1.4 * np.stack([np.sin(heading), np.cos(heading)], 1)
    t_mid = rng.uniform(0.0, duration_s - 30.0, n_walk)
    rows_t, rows_e, xy = [], [], []
    for e in range(n_static):
        rows_t.append(t)
        rows_e.append(np.full(len(t), e))
        xy.append(np.repeat(xy_static[e][None, :], len(t), 0))
    for w in range(n_walk):
        keep = (t >= t_mid[w]) & (t < t_mid[w] + 30.0)
        rows_t.append(t[keep])
        rows_e.append(np.full(int(keep.sum()), n_static + w))
        xy.append(mid[w] + (t[keep] - t_mid[w])[:, None] * v[w])
    tt, em, pos = np.concatenate(rows_t), np.concatenate(rows_e), np.concatenate(xy)
    order = np.argsort(tt, kind="stable")
    tt, em, pos = tt[order], em[order], pos[order]
    true = np.degrees(np.arctan2(pos[:, 0], pos[:, 1]))  # the sensor faces +y
    peak = 15.0 - free_space_path_loss_db(np.hypot(pos[:, 0], pos[:, 1]), 2437.0)
    r = rssi_pairs(true, peak, ANT, RX, rng)
    return true, r, em, (tt * 1e9).astype(np.int64), n_static


@pytest.mark.parametrize("seed", [11, 12])
def test_static_emitters_all_around_a_fixed_sensor_need_to_prove_their_front(cal, seed) -> None:  # type: ignore[no-untyped-def]
    true, r, em, t_ns, n_static = _fixed_sensor(seed)
    ch = np.full(len(true), CHANNEL)

    def run(guard):  # type: ignore[no-untyped-def]
        res = guard.apply(cal, estimate(cal, r[:, 0], r[:, 1], ch), r[:, 0], r[:, 1], ch, em, t_ns)
        v = res.valid
        return res, _confident_wrong_share(res.angle_deg[v], res.sigma_deg[v], true[v])

    # the level rule alone: a static emitter behind or beside has no brighter front level
    _, without = run(FovGuard())
    assert without > 0.15, without
    res, share = run(FovGuard.for_mount(moving=False))  # the default for a fixed mount
    assert share <= CONFIDENT_WRONG_MAX, share
    # static emitters never prove they are in front: none of their bearings count
    assert not res.valid[em < n_static].any()
    # the price: walkers in the field of view count once they have swept a few degrees
    walkers_front = (em >= n_static) & (np.abs(true) <= 20.0)
    assert np.mean(res.valid[walkers_front]) > 0.3, np.mean(res.valid[walkers_front])


def test_the_corner_ap_behind_rsu_nw_in_the_bundled_crossing() -> None:
    from pathlib import Path

    from rfsas_hw.twin.scenario import load_scenario
    from rfsas_hw.twin.world import World

    examples = Path(__file__).resolve().parents[2] / "examples"
    scenario = load_scenario(examples / "crossing.yaml")
    names = [e.id for e in scenario.spec.emitters]
    rec = World(scenario).receptions("rsu-nw")
    obs = rec.observations()
    rsu = load_calibration(examples / "calibration" / "rsu-nw.yaml")
    r = obs.rssi_dbm
    true = rec.true_relative_deg[rec.heard.any(axis=1)]
    ap = rec.emitter[rec.heard.any(axis=1)] == names.index("corner-ap")

    def run(guard):  # type: ignore[no-untyped-def]
        res = estimate(rsu, r[:, 0], r[:, 1], obs.channel)
        res = guard.apply(rsu, res, r[:, 0], r[:, 1], obs.channel, obs.mac, obs.t_ns)
        wrong = res.valid & (np.abs(_wrap(res.angle_deg - true)) > 3.0 * res.sigma_deg)
        return res, wrong

    res, wrong = run(FovGuard())
    assert np.all(np.abs(true[ap]) > 170.0)  # the AP stands behind the sensor
    assert wrong[ap].sum() > 50  # all its bearings confident-wrong without the rule
    res, wrong = run(FovGuard.for_mount(moving=False))
    assert not res.valid[ap].any()
    assert wrong.sum() <= CONFIDENT_WRONG_MAX * res.valid.sum()
    assert res.valid[~ap].mean() > 0.4  # the price: the phone's first seconds


def test_the_guard_for_a_mount() -> None:
    assert FovGuard.for_mount(moving=False).prove_motion_deg == PROVE_MOTION_DEG
    assert FovGuard.for_mount(moving=True).prove_motion_deg == 0.0
    assert FovGuard.for_mount(moving=True, prove_motion_deg=2.0).prove_motion_deg == 2.0
    assert FovGuard.for_mount(moving=False, prove_motion_deg=0.0).prove_motion_deg == 0.0
    assert FovGuard.for_mount(moving=False, warmup_s=5.0).warmup_ns == 5_000_000_000
    with pytest.raises(ValueError, match="prove_motion_deg"):
        FovGuard.for_mount(moving=False, prove_motion_deg=-1.0)


def test_a_moving_mount_keeps_an_emitter_on_a_collision_course(cal) -> None:  # type: ignore[no-untyped-def]
    # a sensor on a car closing in at 20 m/s on a phone 5° off its boresight: the
    # bearing stays put while the range falls from 150 m to 10 m (7 s, 5 frames/s)
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 7.0, 0.2)
    true = np.full(len(t), 5.0)
    peak = 15.0 - free_space_path_loss_db(150.0 - 20.0 * t, 2437.0)
    r = rssi_pairs(true, peak, ANT, RX, rng)
    ch = np.full(len(t), CHANNEL)
    t_ns = (t * 1e9).astype(np.int64)

    def kept(guard: FovGuard) -> float:
        res = estimate(cal, r[:, 0], r[:, 1], ch)
        res = guard.apply(cal, res, r[:, 0], r[:, 1], ch, np.zeros(len(t)), t_ns)
        return float(res.valid.mean())

    assert kept(FovGuard.for_mount(moving=False)) == 0.0  # the motion rule refuses it all
    assert kept(FovGuard.for_mount(moving=True)) > 0.8


def test_fold_drop_shrinks_the_level_margin_towards_the_edge(cal) -> None:  # type: ignore[no-untyped-def]
    t = cal.tables[0]
    drop = fold_drop_db(t.grid_deg, t.psi, t.level_db, t.fov_deg)
    at = {a: float(np.interp(a, t.grid_deg, drop)) for a in (-40.0, -30.0, -10.0, 30.0)}
    # the test antenna: −30° folds onto about −63°, 10 dB weaker; −40° onto about −52°,
    # under 4 dB; near boresight the fold lies far behind, 20 dB and more down
    assert 8.0 < at[-30.0] < 12.0 and at[-40.0] < 4.5 and at[-10.0] > 18.0
    assert 8.0 < at[30.0] < 12.0
    assert np.isnan(drop[t.grid_deg < t.fov_deg[0]]).all()  # no bearing out there
    # half the drop, less the reference's decay, at most the fixed margin
    m = fold_margin_db(np.array([at[-30.0], at[-30.0], at[-10.0], np.nan]), [0.0, 2.0, 0.0, 0.0])
    assert m[0] == pytest.approx(at[-30.0] / 2) and m[1] == pytest.approx(at[-30.0] / 2 - 2)
    assert m[2] == LEVEL_MARGIN_DB and np.isnan(m[3])
    # a table without a level curve has no folds to tell apart: the fixed margin
    doc = calibration_to_mapping(cal)
    del doc["tables"][0]["level_db"]
    old = calibration_from_mapping(doc, "old.yaml")
    res = estimate(old, np.array([-50.0]), np.array([-60.0]), np.array([CHANNEL]))
    assert fold_drops(old, res, [CHANNEL])[0] == np.inf


def test_walkers_just_beyond_the_edge_are_refused_by_their_fold(cal) -> None:  # type: ignore[no-untyped-def]
    # seed 16 of the fixed-sensor set, 600 s: walkers just beyond the edge (−47…−65°)
    # fold onto ≈ −31° only 6–7 dB below their front level, inside the fixed 6 dB margin
    true, r, em, t_ns, n_static = _fixed_sensor(16, 600.0)
    ch = np.full(len(true), CHANNEL)

    def run(folds: bool):  # type: ignore[no-untyped-def]
        guard = FovGuard.for_mount(moving=False)
        est = estimate(cal, r[:, 0], r[:, 1], ch)
        res = guard.apply(cal, est, r[:, 0], r[:, 1], ch, em, t_ns, folds=folds)
        v = res.valid
        return res, _confident_wrong_share(res.angle_deg[v], res.sigma_deg[v], true[v])

    _, fixed_margin = run(False)
    assert fixed_margin > CONFIDENT_WRONG_MAX, fixed_margin
    res, share = run(True)
    assert share <= CONFIDENT_WRONG_MAX, share
    walkers_front = (em >= n_static) & (np.abs(true) <= 45.0)
    assert np.mean(res.valid[walkers_front]) > 0.25, np.mean(res.valid[walkers_front])
