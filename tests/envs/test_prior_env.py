"""The RF activity prior in the environment's observation, and the corners scenario."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("gymnasium", reason="needs the sim extra: pip install 'rfsas-hw[sim]'")

from rfsas_hw.backend.prior import ActivityPrior
from rfsas_hw.envs.env import OBS_SIZE, IntersectionEnv
from rfsas_hw.envs.envconfig import env_config_from_mapping
from rfsas_hw.envs.history import corner_history
from rfsas_hw.envs.rl import HoldPolicy, run_episode
from rfsas_hw.errors import ConfigError, DataFormatError

CORNERS_PRIOR = {"scenario": {"kind": "corners"}, "prior": {"observe": True}}


@pytest.fixture(scope="module")
def env() -> IntersectionEnv:
    return IntersectionEnv(CORNERS_PRIOR)


def test_the_prior_adds_one_entry_only_when_asked() -> None:
    assert IntersectionEnv().observation_space.shape == (OBS_SIZE,)
    assert IntersectionEnv({"scenario": {"kind": "corners"}}).observation_space.shape == (OBS_SIZE,)


def test_busy_corners_have_a_history_and_the_car_sees_it_ahead(env: IntersectionEnv) -> None:
    config = env.config
    busy = corner_history(config, "busy")
    quiet = corner_history(config, "quiet")
    lane = config.vehicle.lane_x_m, config.obstacle.crossing_y_m
    # 24 h at 40 and 2 crossings per hour: the crossing tile's rate is the history's
    assert busy.rate_per_h(*lane) == pytest.approx(40.0, rel=0.2)
    assert quiet.rate_per_h(*lane) == pytest.approx(2.0, rel=0.6)
    seen = {}
    for corner in ("busy", "quiet"):
        obs, _ = env.reset(seed=3, options={"corner": corner, "crosser": False})
        assert env.observation_space.contains(obs) and obs[OBS_SIZE] == 0.0  # 100 m out
        trace = [float(obs[OBS_SIZE])]
        done = False
        while not done:
            obs, _, term, trunc, info = env.step(0)
            trace.append(float(obs[OBS_SIZE]))
            done = term or trunc
        assert not info["warned"] and not info["collision"]
        seen[corner] = max(trace)
        assert trace[-1] < max(trace)  # past the crossing the prior ahead drops
    assert seen["busy"] > 0.9 and seen["quiet"] < 0.3


def test_busy_corners_produce_more_late_crossers(env: IntersectionEnv) -> None:
    late: dict[str, list[bool]] = {"busy": [], "quiet": []}
    empty: dict[str, list[bool]] = {"busy": [], "quiet": []}
    heard: dict[str, list[bool]] = {"busy": [], "quiet": []}
    for seed in range(400):
        env.reset(seed=seed)
        e = env.episode
        assert e is not None
        empty[e.corner].append(not e.crosser)
        if e.crosser:
            late[e.corner].append(e.late)
            heard[e.corner].append(e.heard)
            assert e.heard == math.isfinite(e.warning_s)
        # a warning at a given distance is a heard phone
        env.reset(seed=seed, options={"reaction_distance_m": 50.0})
        assert env.episode is not None
        assert env.episode.heard == env.episode.crosser
    # a quarter of the crossers are never heard, at either kind of corner
    assert np.mean(heard["busy"]) == pytest.approx(0.75, abs=0.1)
    assert np.mean(heard["quiet"]) == pytest.approx(0.75, abs=0.1)
    assert 150 < len(empty["busy"]) < 250
    assert np.mean(late["busy"]) == pytest.approx(0.75, abs=0.08)
    assert np.mean(late["quiet"]) == pytest.approx(0.15, abs=0.08)
    assert np.mean(empty["busy"]) < np.mean(empty["quiet"])
    # and a car that ignores warnings hits more often at busy corners
    hits = {"busy": 0, "quiet": 0}
    for seed in range(60):
        for corner in hits:
            info = run_episode(env, HoldPolicy(), seed, options={"corner": corner})
            hits[info["corner"]] += info["collision"]
    assert hits["busy"] > 2 * hits["quiet"]


def test_options_fix_the_draw_and_change_nothing_else(env: IntersectionEnv) -> None:
    env.reset(seed=11, options={"corner": "busy"})
    a = env.episode
    env.reset(seed=11, options={"corner": "busy", "heard": False})
    b = env.episode
    assert a is not None and b is not None
    assert (a.initial_speed_mps, a.obstacle_arrival_s) == (
        b.initial_speed_mps,
        b.obstacle_arrival_s,
    )
    assert b.warning_s == np.inf and not b.heard
    with pytest.raises(ConfigError, match="corner"):
        env.reset(seed=1, options={"corner": "noisy"})
    with pytest.raises(ConfigError, match="unknown key"):
        env.reset(seed=1, options={"weather": "rain"})


def test_the_prior_can_come_from_a_file(tmp_path: Path) -> None:
    prior = ActivityPrior()
    prior.add_fix(1_767_225_600 * 10**9, 1.75, -3.5, "x")
    prior.observe(1_767_225_630 * 10**9)
    path = prior.save(tmp_path / "prior.json")
    env = IntersectionEnv({"prior": {"observe": True, "path": str(path)}})
    env.reset(seed=0)
    env.front_y_m = -20.0
    assert env.prior_ahead > 0.99  # 120 visits per hour on the lane
    config = env_config_from_mapping({"prior": {"observe": True, "path": str(tmp_path / "x")}})
    with pytest.raises(DataFormatError, match="prior"):
        IntersectionEnv(config)


def test_the_env_with_the_prior_passes_the_checkers(env: IntersectionEnv) -> None:
    from gymnasium.utils.env_checker import check_env

    check_env(env, skip_render_check=True)
    sb3_checker = pytest.importorskip(
        "stable_baselines3.common.env_checker", reason="needs the rl extra: make rl"
    )
    sb3_checker.check_env(env, warn=True)


def test_a_long_history_gives_an_hour_of_day_prior(tmp_path: Path) -> None:
    # eight days observed every 30 s; crossers on the lane only between 08:00 and 09:00 UTC
    prior = ActivityPrior()
    t0 = 1_767_225_600  # 2026-01-01T00:00:00Z
    for k in range(8 * 24 * 120):
        t = t0 + 30 * k
        if (t // 3600) % 24 == 8 and k % 4 == 0:
            prior.add_fix(t * 10**9, 1.75, -3.5, f"e{k}")
        prior.observe(t * 10**9)
    assert prior.hourly
    path = prior.save(tmp_path / "prior.json")
    env = IntersectionEnv({"prior": {"observe": True, "path": str(path)}})
    seen = {}
    for hour in (8, 20):
        env.reset(seed=0, options={"hour": hour})
        assert env.episode is not None and env.episode.hour == hour
        env.front_y_m = -20.0
        seen[hour] = env.prior_ahead
    # 30 visits an hour at 08 (one every two minutes), none at 20
    assert seen[8] == pytest.approx(1 - np.exp(-30 / 20), abs=0.02) and seen[20] == 0.0
    # without the option each episode draws its hour, after every other draw
    hours = set()
    for seed in range(40):
        env.reset(seed=seed)
        assert env.episode is not None and env.episode.hour is not None
        hours.add(env.episode.hour)
    assert len(hours) > 10
    pinned = IntersectionEnv({"prior": {"observe": True, "path": str(path), "hour": 8}})
    pinned.reset(seed=5)
    assert pinned.episode is not None and pinned.episode.hour == 8
    with pytest.raises(ConfigError, match="hour"):
        env.reset(seed=1, options={"hour": 24})
    # a one-day history is pooled: the hour is not drawn and changes nothing
    short = IntersectionEnv({"prior": {"observe": True}})
    short.reset(seed=0, options={"hour": 3})
    assert short.episode is not None and short.episode.hour is None
