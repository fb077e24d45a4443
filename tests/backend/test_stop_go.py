"""The stop-and-go motion model (``tracker.stop_go``): a walker who stops, one who starts."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from backendhelp import one_bearing

from rfsas_hw.backend.association import AssociationConfig
from rfsas_hw.backend.bearing_tracking import BearingUpdateConfig
from rfsas_hw.backend.service import BackendConfig, BackendService, load_backend_config
from rfsas_hw.backend.stop_go import STANDING, Modes, StopGoConfig, combine, reweigh
from rfsas_hw.backend.tracking import Tracker, TrackerConfig, predict_tracks
from rfsas_hw.bridges.config import BACKEND_PROFILES
from rfsas_hw.errors import BackendError, ConfigError
from rfsas_hw.records import BearingBatch, Pose

S = 1_000_000_000
EMITTER = 9
RSU = np.array([4.0, 7.0])
SIGMA_DEG = 3.0
_MATRIX = BACKEND_PROFILES["urban-intersection-bearings"].tracker.stop_go
assert _MATRIX is not None
STOP_GO: StopGoConfig = _MATRIX
"""The Euro NCAP matrix's settings."""


def _batch(sensor: str, t_ns: int, azimuth_deg: float) -> BearingBatch:
    return one_bearing(sensor, t_ns, azimuth_deg, SIGMA_DEG, EMITTER)


def _run(
    stop_go: StopGoConfig | None,
    rng: np.random.Generator,
    where: Callable[[float], np.ndarray],
    steps: int,
) -> list[np.ndarray]:
    """Bearings of 3° every 0.1 s from the roadside unit and from a car's unit driving
    east along y = 0 at 30 km/h from x = −40 m (bearings-fed tracks); the track's
    velocity after each step (NaN before it starts)."""
    svc = BackendService(
        BackendConfig(
            association=AssociationConfig(window_s=0.5),
            tracker=TrackerConfig(stop_go=stop_go),
            tracking="bearings",
            bearings=BearingUpdateConfig(start_sigma_scale=2.0),
        )
    )
    out = []
    for k in range(steps):
        t = k * S // 10
        target = where(k * 0.1)
        car = np.array([-40.0 + 8.33 * k * 0.1, 0.0])
        for sensor, pos in (("rsu", RSU), ("car", car)):
            d = target - pos
            az = math.degrees(math.atan2(d[0], d[1])) + SIGMA_DEG * rng.standard_normal()
            svc.on_bearings(_batch(sensor, t, az), Pose(float(pos[0]), float(pos[1]), 90.0))
        svc.step(t + 1)
        track = svc.tracker.tracks.get(EMITTER)
        out.append(track.velocity if track is not None else np.full(2, np.nan))
    return out


def _walk_then_stop(t_s: float) -> np.ndarray:
    # north at 1.4 m/s from 6 m right of the lane until 2.0 s, then standing at the kerb
    return np.array([0.0, -6.0 + 1.4 * min(t_s, 2.0)])


def _stand_then_go(t_s: float) -> np.ndarray:
    # standing 4.5 m right of the lane until 2.0 s, then riding north at 2.8 m/s
    return np.array([0.0, -4.5 + 2.8 * max(t_s - 2.0, 0.0)])


def _median_time(vels: list[list[np.ndarray]], done: Callable[[float], bool]) -> float:
    """Median over runs of the first time (s after 2.0 s) from which ``done(vy)`` holds
    for the rest of the run (inf: never)."""
    times = []
    for run in vels:
        vy = [float(v[1]) for v in run]
        first = math.inf
        for k in range(len(vy) - 1, 19, -1):
            if not done(vy[k]):
                break
            first = (k - 20) * 0.1
        times.append(first)
    return float(np.median(times))


def test_a_walker_who_stops_is_believed_stopped_sooner() -> None:
    runs = 40
    stopped: dict[str, float] = {}
    for name, model in (("cv", None), ("stop-go", STOP_GO)):
        rng = np.random.default_rng(4)
        vels = [_run(model, rng, _walk_then_stop, 40) for _ in range(runs)]
        stopped[name] = _median_time(vels, lambda vy: abs(vy) < 0.3)
    # measured: constant velocity 1.8 s, stop-and-go 1.4 s after the stop
    assert stopped["stop-go"] <= 1.6
    assert stopped["stop-go"] < stopped["cv"] - 0.3


def test_a_standing_rider_who_starts_is_believed_moving_within_a_second() -> None:
    # the price of believing a stop sooner: a start is believed later (the standing
    # model must first lose the likelihood contest), here by 0.2 s
    runs = 40
    moving: dict[str, float] = {}
    for name, model in (("cv", None), ("stop-go", STOP_GO)):
        rng = np.random.default_rng(11)
        vels = [_run(model, rng, _stand_then_go, 35) for _ in range(runs)]
        moving[name] = _median_time(vels, lambda vy: vy > 1.4)
    # measured: constant velocity 0.8 s, stop-and-go 1.0 s after the start
    assert moving["stop-go"] <= 1.2
    assert moving["stop-go"] <= moving["cv"] + 0.3


def test_transition_combination_and_weights() -> None:
    cfg = StopGoConfig(stop_per_s=0.4, go_per_s=0.1, standing_sigma_mps=0.2)
    assert np.allclose(cfg.transition(0.0), np.eye(2))
    T = cfg.transition(0.1)
    assert np.allclose(T.sum(axis=1), 1.0)
    assert T[0, 1] == pytest.approx(0.04, rel=0.03)  # ≈ rate · dt for a short dt
    # the long run: the chain's own shares, whatever it started from
    assert np.allclose(cfg.transition(1e3), [[0.2, 0.8], [0.2, 0.8]])
    assert cfg.standing_share == pytest.approx(0.8)
    # the combination: the mixture's mean and covariance (spread of the means included)
    xs = np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 0.0]])
    Ps = np.array([np.eye(4), np.eye(4)])
    x, P = combine(xs, Ps, np.array([0.5, 0.5]))
    assert x[2] == pytest.approx(0.5)
    assert P[2, 2] == pytest.approx(1.25) and P[0, 0] == pytest.approx(1.0)
    # weights from log-likelihoods far apart do not underflow; none at all keep the prior
    assert np.allclose(reweigh(np.array([0.5, 0.5]), np.array([-2000.0, -1000.0])), [0, 1])
    assert np.allclose(reweigh(np.array([0.3, 0.7]), np.array([-np.inf, -np.inf])), [0.3, 0.7])
    with pytest.raises(BackendError, match="go_per_s"):
        StopGoConfig(go_per_s=0.0)


def test_fix_fed_tracks_and_the_one_prediction() -> None:
    # a standing emitter seen by fixes: the standing model gains weight (a constant
    # velocity near 0 explains them nearly as well: 0.43 against 0.29), the velocity
    # is no further from 0, and the prediction every reader uses is the models' mixture
    rng = np.random.default_rng(2)
    plain = Tracker(TrackerConfig())
    mixed = Tracker(TrackerConfig(stop_go=STOP_GO))
    R = np.eye(2) * 0.25
    for k in range(30):
        z = np.array([3.0, -2.0]) + rng.normal(0, 0.5, 2)
        for tracker in (plain, mixed):
            tracker.update(EMITTER, k * S // 10, z, R)
    a, b = plain.tracks[EMITTER], mixed.tracks[EMITTER]
    assert a.modes is None and b.modes is not None
    assert b.modes.probs[STANDING] > STOP_GO.standing_share
    assert np.hypot(*b.velocity) < np.hypot(*a.velocity) + 0.05
    x, P = predict_tracks([a, b], 4 * S, 1.0)
    x_b, P_b = b.predict(4 * S, 1.0)
    np.testing.assert_allclose(x[1], x_b)
    np.testing.assert_allclose(P[1], P_b)
    assert np.all(np.linalg.eigvalsh(P[1]) > 0)
    # a far fix restarts the track with both models again
    mixed.update(EMITTER, 31 * S // 10, np.array([40.0, 40.0]), R)
    assert mixed.stats.restarted == 1 and mixed.tracks[EMITTER].updates == 1
    fresh = mixed.tracks[EMITTER].modes
    assert isinstance(fresh, Modes)
    assert fresh.probs[STANDING] == pytest.approx(STOP_GO.standing_share)


def test_only_the_matrix_profile_uses_it_and_a_file_sets_it(tmp_path: Path) -> None:
    assert TrackerConfig().stop_go is None
    users = {n for n, p in BACKEND_PROFILES.items() if p.tracker.stop_go is not None}
    assert users == {"urban-intersection-bearings"}
    good = tmp_path / "backend.yaml"
    good.write_text("tracker: {stop_go: {stop_per_s: 0.8, standing_sigma_mps: 0.3}}\n")
    cfg = load_backend_config(good).tracker.stop_go
    assert cfg == StopGoConfig(stop_per_s=0.8, go_per_s=0.5, standing_sigma_mps=0.3)
    bad = tmp_path / "bad.yaml"
    bad.write_text("tracker: {stop_go: {go_per_s: -1}}\n")
    with pytest.raises(ConfigError, match="go_per_s"):
        load_backend_config(bad)
