"""The intersection environment: API conformance, seeding, dynamics, reward, warning, sensing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("gymnasium", reason="needs the sim extra: pip install 'rfsas-hw[sim]'")

import gymnasium as gym
from gymnasium.utils.env_checker import check_env

import rfsas_hw.envs
from rfsas_hw.backend.risk import fatality_risk
from rfsas_hw.envs.env import ACCELERATE, BRAKE, COAST, IntersectionEnv
from rfsas_hw.envs.envconfig import EnvConfig, env_config_from_mapping, load_env_config
from rfsas_hw.envs.threat import SensorPoses, make_locator
from rfsas_hw.errors import ConfigError


def run(env: IntersectionEnv, actions: list[int], **reset: object) -> list[tuple[object, ...]]:
    """Observations, rewards and flags of an action sequence (stops at the episode's end)."""
    obs, _ = env.reset(**reset)  # type: ignore[arg-type]
    out: list[tuple[object, ...]] = [tuple(obs.tolist())]
    for a in actions:
        obs, r, term, trunc, info = env.step(a)
        out.append((tuple(obs.tolist()), r, term, trunc, info["collision"]))
        if term or trunc:
            break
    return out


@pytest.mark.parametrize("detail", ["low", "medium", "high"])
def test_gymnasium_check_env_passes_without_warnings(detail: str) -> None:
    env = IntersectionEnv({"sensing": {"detail": detail}})
    check_env(env, skip_render_check=True)


def test_stable_baselines3_check_env_passes() -> None:
    sb3_checker = pytest.importorskip(
        "stable_baselines3.common.env_checker",
        reason="stable-baselines3 is not installed (make rl)",
    )
    sb3_checker.check_env(IntersectionEnv(), warn=True)


def test_registered_on_import_of_the_sim_package() -> None:
    env = gym.make(rfsas_hw.envs.ENV_ID, config={"sensing": {"detail": "low"}})
    assert env.spec is not None and env.spec.id == "rfsas/Intersection-v0"
    obs, _ = env.reset(seed=1)
    assert env.observation_space.contains(obs)
    env.close()


@pytest.mark.parametrize("detail", ["low", "medium", "high"])
def test_same_seed_same_trajectory_other_seed_differs(detail: str) -> None:
    env = IntersectionEnv({"sensing": {"detail": detail}})
    actions = [COAST] * 30 + [BRAKE] * 10 + [ACCELERATE] * 40
    first = run(env, actions, seed=11)
    again = run(env, actions, seed=11)
    other = run(env, actions, seed=12)
    assert first == again
    assert first != other


def test_speed_is_clamped_and_never_negative_and_a_stop_does_not_end_the_episode() -> None:
    # A stop used to end the episode and count as safe: agents learned to stop short of
    # busy corners. Now the car has to drive on, and time passes while it waits.
    env = IntersectionEnv({"vehicle": {"initial_speed_mps": [15.0, 15.0]}})
    env.reset(seed=3)
    speeds = []
    for _ in range(40):
        _, _, term, _, info = env.step(ACCELERATE)
        speeds.append(info["speed_mps"])
        if term:
            break
    assert max(speeds) == pytest.approx(20.0)
    assert speeds[0] == pytest.approx(15.2)
    env.reset(seed=3, options={"crosser": True})
    y0 = env.front_y_m
    clock = []
    for _ in range(60):
        obs, _, term, trunc, info = env.step(BRAKE)
        assert info["speed_mps"] >= 0.0
        assert not (term or trunc)
        clock.append(float(obs[6]))
    assert info["speed_mps"] == 0.0 and not info["collision"] and not info["crossed"]
    assert env.t_s == pytest.approx(6.0)  # a stopped car's clock runs on
    # and the car sees it: the episode clock is the one entry that changes while it waits
    assert clock == pytest.approx([k / 600 for k in range(1, 61)])
    # 15 m/s braking at 4.7 m/s² stops in 15²/(2·4.7) m
    assert env.front_y_m - y0 == pytest.approx(15.0**2 / (2 * 4.7), abs=1e-9)
    for _ in range(200):
        _, _, term, trunc, info = env.step(ACCELERATE)
        if term or trunc:
            break
    # the cyclist has long passed: the car drives on and crosses
    assert term and info["crossed"] and not info["collision"]


def test_a_car_that_never_crosses_times_out_and_pays_for_it() -> None:
    config = {"reward": {"kind": "risk-progress"}, "max_steps": 50}
    env = IntersectionEnv(config)
    env.reset(seed=0)
    total = 0.0
    for k in range(50):
        _, r, term, trunc, info = env.step(BRAKE)
        total += float(r)
        assert not term
        assert trunc == (k == 49)
    assert not info["crossed"]
    covered = (env.front_y_m + 100.0) / 100.0
    # progress, minus 0.1 per second, minus 1 for the timeout
    assert total == pytest.approx(covered - 0.1 * 5.0 - 1.0)


def test_reaching_the_intersection_ends_the_episode() -> None:
    env = IntersectionEnv()
    env.reset(seed=0, options={"reaction_distance_m": 0.0})
    for _ in range(200):
        _, _, term, trunc, info = env.step(ACCELERATE)
        if term or trunc:
            break
    assert term and not trunc
    assert env.front_y_m >= env.config.end_y_m or info["collision"]


def test_reaction_distance_option_places_the_warning() -> None:
    env = IntersectionEnv()
    obs, info = env.reset(seed=5, options={"reaction_distance_m": 60.0})
    assert info["reaction_distance_m"] == pytest.approx(60.0)
    assert obs[5] == 0.0
    warned_at = None
    while warned_at is None:
        obs, _, _, _, info = env.step(COAST)
        if info["warned"]:
            warned_at = info["distance_m"]
    # a car holding its speed is warned within one step of 60 m
    assert 60.0 - 20.0 * env.config.dt_s - 1e-9 <= warned_at <= 60.0 + 1e-9
    assert obs[5] == 1.0


def test_default_reset_places_the_warning_from_delay_and_buildings() -> None:
    """Without RF the warning comes when the building stops hiding the cyclist, plus the delay."""
    no_rf = IntersectionEnv({"sensing": {"intercept_s": [30.0, 30.0]}})
    rf = IntersectionEnv({"sensing": {"intercept_s": [0.0, 0.0], "reaction_delay_s": 0.5}})
    for seed in range(5):
        _, info = no_rf.reset(seed=seed)
        ep = no_rf.episode
        assert ep is not None
        assert info["warning_s"] == pytest.approx(ep.los_s + 0.2)
        # the building hides the cyclist for a while
        assert ep.los_s > 1.0
        assert info["reaction_distance_m"] < 80.0
        _, info = rf.reset(seed=seed)
        assert info["warning_s"] == pytest.approx(0.5)
        assert info["reaction_distance_m"] == pytest.approx(100.0 - 0.5 * 20.0)


def test_reset_rejects_unknown_and_bad_options() -> None:
    env = IntersectionEnv()
    with pytest.raises(ConfigError, match="unknown key 'distance'"):
        env.reset(seed=0, options={"distance": 3})
    with pytest.raises(ConfigError, match="must be ≥ 0"):
        env.reset(seed=0, options={"reaction_distance_m": -1})


def test_method_reward_follows_the_estimated_risk_seen_by_the_agent() -> None:
    env = IntersectionEnv()
    env.reset(seed=2, options={"reaction_distance_m": 100.0})
    threshold = env.config.risk_threshold
    rng = np.random.default_rng(0)
    seen_above = seen_below = False
    for _ in range(200):
        risk = env.assessment.risk
        a = int(rng.integers(0, 3)) if env.speed_mps > 6 else ACCELERATE
        _, r, term, trunc, _ = env.step(a)
        above = risk > threshold
        seen_above |= above
        seen_below |= not above
        expected = 1.0 if (a == BRAKE and above) or (a == ACCELERATE and not above) else 0.0
        assert r == expected
        if term or trunc:
            break
    assert seen_below


def test_risk_progress_reward_pays_progress_and_charges_realised_risk() -> None:
    env = IntersectionEnv({"reward": {"kind": "risk-progress", "risk_weight": 10.0}})
    total = 0.0
    for seed in range(40):
        env.reset(seed=seed, options={"reaction_distance_m": 0.0})
        total = 0.0
        done = False
        while not done:
            y0 = env.front_y_m
            _, r, term, trunc, info = env.step(COAST)
            done = term or trunc
            expected = (env.front_y_m - y0) / 100.0 - 0.1 * 0.1
            if info["collision"]:
                expected -= 10.0 * fatality_risk(info["impact_speed_mps"])
            assert float(r) == pytest.approx(expected)
            total += float(r)
        if info["collision"]:
            break
    assert info["collision"], "no collision in 40 episodes holding 20 m/s"
    assert total < 1.0


def test_collision_uses_true_positions_and_records_the_impact_speed() -> None:
    env = IntersectionEnv()
    hits = 0
    for seed in range(30):
        env.reset(seed=seed, options={"reaction_distance_m": 0.0})
        done = False
        while not done:
            _, _, term, trunc, info = env.step(COAST)
            done = term or trunc
        if info["collision"]:
            hits += 1
            assert info["impact_speed_mps"] == pytest.approx(20.0)
            car_x, car_y = env.vehicle_xy()
            ob = env.obstacle_xy()
            assert abs(ob[0] - car_x) < (1.8 + 1.8) / 2
            assert abs(ob[1] - car_y) < (4.5 + 0.6) / 2
            assert info["realised_risk"] == pytest.approx(fatality_risk(20.0))
    # about half of the cyclists' arrival times meet a car holding 20 m/s
    assert 5 <= hits <= 25


def test_config_rejects_unknown_keys_with_their_path() -> None:
    with pytest.raises(ConfigError, match=r"env\.vehicle: unknown key 'speed'"):
        env_config_from_mapping({"vehicle": {"speed": 3}})
    with pytest.raises(ConfigError, match=r"env\.sensing\.detail"):
        env_config_from_mapping({"sensing": {"detail": "ultra"}})
    with pytest.raises(ConfigError, match="initial_speed_mps"):
        env_config_from_mapping({"vehicle": {"initial_speed_mps": [25, 30]}})
    with pytest.raises(ConfigError, match="render_mode"):
        IntersectionEnv(render_mode="ascii")


@pytest.mark.parametrize("detail", ["medium", "high"])
def test_rf_locators_find_the_obstacle_within_their_covariance(detail: str) -> None:
    """Fixes from bearings land near the truth, with errors the covariance accounts for."""
    config = env_config_from_mapping({"sensing": {"detail": detail}})
    locator = make_locator(config)
    env = IntersectionEnv(config)
    env.reset(seed=0)
    rng = np.random.default_rng(1)
    truth = np.array([-12.0, -3.5])
    poses = SensorPoses(roadside=env.sensor_poses().roadside, obu=env.sensor_poses().obu)
    d2 = []
    for _ in range(200):
        fix = locator.locate(0.0, truth, poses, rng)
        if fix is None:
            continue
        err = fix.position - truth
        d2.append(float(err @ np.linalg.solve(fix.covariance, err)))
        assert len(fix.bearings) >= 2
    assert len(d2) > 100
    # Mahalanobis² of a 2-D Gaussian has mean 2; calibration bias makes the pipeline worse
    assert np.median(d2) < (3.0 if detail == "medium" else 12.0)


def test_estimated_risk_rises_for_a_conflict_and_stays_low_without_one() -> None:
    env = IntersectionEnv()
    peaks = {}
    for seed in range(12):
        env.reset(seed=seed, options={"reaction_distance_m": 100.0})
        peak = 0.0
        done = False
        while not done:
            _, _, term, trunc, info = env.step(COAST)
            peak = max(peak, info["risk"])
            done = term or trunc
        peaks[seed] = (peak, info["collision"])
    hit = [p for p, c in peaks.values() if c]
    miss = [p for p, c in peaks.values() if not c]
    assert hit and miss
    assert min(hit) > EnvConfig().risk_threshold
    assert np.median(miss) < min(hit)


def test_config_file_errors_name_the_file(tmp_path: Path) -> None:
    good = tmp_path / "env.yaml"
    good.write_text("risk_threshold: 0.01\nsensing:\n  detail: medium\n")
    config = load_env_config(good)
    assert config.risk_threshold == 0.01 and config.sensing.detail == "medium"
    bad = tmp_path / "bad.yaml"
    bad.write_text("sensing:\n  detial: medium\n")
    with pytest.raises(ConfigError, match=r"bad\.yaml.*'detial'"):
        load_env_config(bad)
