"""The change test on a standing track (``bearings.start_test``): calibrated under
"standing", silent on a target that stands, quick on one that starts."""

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
from rfsas_hw.backend.start_test import StartTestConfig, StartWindow
from rfsas_hw.backend.stop_go import StopGoConfig
from rfsas_hw.backend.tracking import TrackerConfig
from rfsas_hw.bridges.config import BACKEND_PROFILES
from rfsas_hw.errors import BackendError, ConfigError
from rfsas_hw.records import BearingBatch, Pose

S = 1_000_000_000
EMITTER = 9
SIGMA_DEG = 3.0
SENSORS = {"rsu": np.array([4.0, 7.0]), "kerb": np.array([8.0, -3.5])}
ARMED = StartTestConfig(armed_standing_prob=0.3)
"""Armed from a standing probability of 0.3: with these two units a waiting target's
hovers about 0.5 (a constant velocity near 0 explains it nearly as well)."""


def _batch(sensor: str, t_ns: int, azimuth_deg: float) -> BearingBatch:
    return one_bearing(sensor, t_ns, azimuth_deg, SIGMA_DEG, EMITTER)


def _run(
    test: StartTestConfig | None,
    rng: np.random.Generator,
    where: Callable[[float], np.ndarray],
    steps: int,
) -> tuple[list[float], int]:
    """Bearings of 3° every 0.1 s from two roadside units (bearings-fed tracks with the
    standing model); the track's northward velocity after each step (NaN before it
    starts) and how often the start test fired."""
    svc = BackendService(
        BackendConfig(
            association=AssociationConfig(window_s=0.5),
            tracker=TrackerConfig(stop_go=StopGoConfig()),
            tracking="bearings",
            bearings=BearingUpdateConfig(start_sigma_scale=2.0, start_test=test),
        )
    )
    vy = []
    for k in range(steps):
        t = k * S // 10
        target = where(k * 0.1)
        for sensor, pos in SENSORS.items():
            d = target - pos
            az = math.degrees(math.atan2(d[0], d[1])) + SIGMA_DEG * rng.standard_normal()
            svc.on_bearings(_batch(sensor, t, az), Pose(float(pos[0]), float(pos[1]), 270.0))
        svc.step(t + 1)
        track = svc.tracker.tracks.get(EMITTER)
        vy.append(float(track.velocity[1]) if track is not None else math.nan)
    assert svc.bearing_tracker is not None
    return vy, svc.bearing_tracker.stats.starts


def _stand_then_go(t_s: float) -> np.ndarray:
    # waiting 4.5 m right of the lane for 4 s, then riding north at 2.8 m/s
    return np.array([0.0, -4.5 + 2.8 * max(t_s - 4.0, 0.0)])


def _believed_moving_s(vy: list[float]) -> float:
    """Seconds after the start (at 4.0 s) from which the track's northward speed
    stays above half the rider's (inf: never)."""
    first = math.inf
    for k in range(len(vy) - 1, 39, -1):
        if not vy[k] > 1.4:
            break
        first = (k - 40) * 0.1
    return first


def test_the_statistic_is_chi2_with_two_degrees_under_standing() -> None:
    # the linear model the test assumes, one onset (window = min_readings), a standing
    # target drawn from the prior: the statistic is χ²₂, P(> h) = exp(−h/2)
    rng = np.random.default_rng(5)
    n, trials, h = 12, 2000, 4.6
    cfg = StartTestConfig(threshold=h, window_s=10.0, min_readings=n)
    P = np.array([[0.2, 0.05], [0.05, 0.1]])
    sensors = np.array([[6.0, -3.5], [4.0, 7.0], [-20.0, 0.0]])
    fired = 0
    for _ in range(trials):
        window = StartWindow(cfg)
        q = rng.multivariate_normal(np.zeros(2), P)  # the target, about p = 0
        for i in range(n):
            s = sensors[i % 3]
            d = -s
            r2 = float(d @ d)
            H = np.array([d[1] / r2, -d[0] / r2])
            R = math.radians(4.0) ** 2
            y = float(H @ q) + math.sqrt(R) * rng.standard_normal()
            window.add(i * S // 10, y, H, R, np.zeros(2), P, 0.5, f"u{i % 3}")
        fired += window.test() is not None
    expected = math.exp(-h / 2)  # 0.100
    sd = math.sqrt(expected * (1 - expected) / trials)  # 0.0067
    assert abs(fired / trials - expected) < 4 * sd, fired / trials


def test_a_standing_target_does_not_fire_it() -> None:
    # 10 runs of 30 s, two units, 3° bearings: about 5,900 tests of up to 7 onsets each
    rng = np.random.default_rng(3)
    starts = 0
    for _ in range(10):
        vy, fired = _run(ARMED, rng, lambda t: np.array([0.0, -4.5]), 300)
        starts += fired
        assert np.nanmax(np.abs(vy[50:])) < 1.0
    assert starts == 0


def test_a_rider_who_starts_is_believed_moving_sooner() -> None:
    runs = 40
    delay: dict[str, float] = {}
    for name, test in (("imm", None), ("start test", ARMED)):
        rng = np.random.default_rng(11)
        out = [_run(test, rng, _stand_then_go, 55) for _ in range(runs)]
        delay[name] = float(np.median([_believed_moving_s(vy) for vy, _ in out]))
        if test is not None:
            assert sum(fired > 0 for _, fired in out) >= runs - 5
    # measured: the standing model alone 1.25 s, with the start test 0.7 s (fired in 38 of 40)
    assert delay["start test"] <= delay["imm"] - 0.3, delay
    assert delay["start test"] <= 0.9, delay


def test_settings_are_checked_and_read_from_a_file(tmp_path: Path) -> None:
    assert BearingUpdateConfig().start_test is None
    for bad in ({"threshold": 0.0}, {"min_readings": 2}, {"moving_prob": 1.5}):
        with pytest.raises(BackendError, match="start_test"):
            StartTestConfig(**bad)  # type: ignore[arg-type]
    path = tmp_path / "backend.yaml"
    path.write_text(
        "tracking: bearings\nbearings: {start_test: {threshold: 25, window_s: 0.8}}\n",
        encoding="utf-8",
    )
    got = load_backend_config(path).bearings.start_test
    assert got == StartTestConfig(threshold=25.0, window_s=0.8)
    path.write_text("bearings: {start_test: {window_s: -1}}\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="window_s"):
        load_backend_config(path)
    window = StartWindow(StartTestConfig())
    window.add(S, 0.0, np.array([0.1, 0.0]), 1e-3, np.zeros(2), np.eye(2), 0.5, "a")
    with pytest.raises(BackendError, match="before the newest"):
        window.add(0, 0.0, np.array([0.1, 0.0]), 1e-3, np.zeros(2), np.eye(2), 0.5, "a")


def test_only_the_matrix_profile_runs_it() -> None:
    users = {n for n, p in BACKEND_PROFILES.items() if p.bearings.start_test is not None}
    assert users == {"urban-intersection-bearings"}
    profile = BACKEND_PROFILES["urban-intersection-bearings"]
    assert profile.tracker.stop_go is not None  # the test runs on the standing model
