"""The risk of driving on in the observation: a stopped car can tell when to go."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("gymnasium", reason="needs the sim extra: pip install 'rfsas-hw[sim]'")

from rfsas_hw.envs.env import (
    BRAKE,
    DRIVE_ON_SIZE,
    OBS_SIZE,
    IntersectionEnv,
    ObsArray,
    observation_size,
)
from rfsas_hw.envs.envconfig import EnvConfig, env_config_from_mapping
from rfsas_hw.envs.presets import preset

CLOCK = 6
"""Index of the episode clock in the observation."""
# the crosser reaches the car's lane 7 s after reset; a car braking from the start
# stops 57 m short of the centre at about 4.3 s, while the crosser is still coming
LATE_CROSSER = {"obstacle": {"lane_arrival_s": [7.0, 7.0]}}


def _stopped(config: dict[str, object]) -> list[tuple[float, ObsArray]]:
    """(time, observation) of every step at a standstill, braking from the start, for 12 s."""
    env = IntersectionEnv(config)
    env.reset(seed=1, options={"reaction_distance_m": 60.0})
    rows: list[tuple[float, ObsArray]] = []
    while env.t_s < 12.0:
        obs, _, terminated, truncated, info = env.step(BRAKE)
        assert not (terminated or truncated)
        if info["speed_mps"] == 0.0:
            rows.append((info["t_s"], obs))
    return rows


def _without_clock(obs: ObsArray) -> ObsArray:
    return np.delete(obs[:OBS_SIZE], CLOCK)


def test_a_stopped_car_sees_whether_the_crosser_is_still_ahead() -> None:
    rows = _stopped({**LATE_CROSSER, "observe_drive_on": True})
    (t_ahead, ahead), (t_passed, passed) = rows[0], rows[-1]
    assert t_ahead < 7.0 < t_passed
    # the car's own picture is the same before and after: stopped, warned, no risk
    np.testing.assert_allclose(_without_clock(ahead), _without_clock(passed), atol=1e-6)
    assert ahead[2] < 1e-6 and ahead[4] < 1e-6
    # driving on would meet the crosser while it is ahead, and nobody once it passed
    log_risk_ahead, p_ahead = ahead[OBS_SIZE:]
    log_risk_passed, p_passed = passed[OBS_SIZE:]
    assert p_ahead > 0.1 and log_risk_ahead > 0.0
    assert p_passed < 1e-6 and log_risk_passed == 0.0


def test_without_drive_on_only_the_clock_tells_them_apart() -> None:
    rows = _stopped(LATE_CROSSER)
    ahead, passed = rows[0][1], rows[-1][1]
    assert ahead.shape == passed.shape == (OBS_SIZE,)
    np.testing.assert_allclose(_without_clock(ahead), _without_clock(passed), atol=1e-6)


def test_drive_on_before_the_warning_is_zero_and_at_full_speed_is_the_own_risk() -> None:
    env = IntersectionEnv({**LATE_CROSSER, "observe_drive_on": True})
    obs, _ = env.reset(seed=1, options={"reaction_distance_m": 60.0})
    assert not env.warned and obs[OBS_SIZE:].tolist() == [0.0, 0.0]
    while not env.warned:
        obs, *_ = env.step(0)  # coast: the car keeps its initial speed
    assert env.speed_mps == env.episode.initial_speed_mps  # type: ignore[union-attr]
    np.testing.assert_array_equal(obs[OBS_SIZE:], [obs[3], obs[4]])


def test_the_protocol_preset_observes_it_and_the_method_preset_does_not() -> None:
    protocol = preset("protocol").apply(EnvConfig())
    method = preset("method").apply(EnvConfig())
    assert protocol.observe_drive_on and not method.observe_drive_on
    assert observation_size(protocol) == OBS_SIZE + DRIVE_ON_SIZE
    assert IntersectionEnv(protocol).observation_space.shape == (OBS_SIZE + DRIVE_ON_SIZE,)
    assert IntersectionEnv(method).observation_space.shape == (OBS_SIZE,)
    with_prior = env_config_from_mapping({"prior": {"observe": True}, "observe_drive_on": True})
    assert observation_size(with_prior) == OBS_SIZE + 1 + DRIVE_ON_SIZE
