"""The RF activity prior in the environment's observation, and the corners scenario."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

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
    for seed in range(400):
        env.reset(seed=seed)
        e = env.episode
        assert e is not None
        empty[e.corner].append(not e.crosser)
        if e.crosser:
            late[e.corner].append(e.late)
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
        "stable_baselines3.common.env_checker", reason="stable-baselines3 is not installed"
    )
    sb3_checker.check_env(env, warn=True)
