"""The warm start: demonstrations of the rule, cloning them into PPO, and the step budget."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("gymnasium", reason="needs the sim extra: pip install 'rfsas-hw[sim]'")

from rfsas_hw.envs.env import ACCELERATE, BRAKE, COAST, IntersectionEnv
from rfsas_hw.envs.envconfig import EnvConfig
from rfsas_hw.envs.presets import preset
from rfsas_hw.envs.rl import RulePolicy
from rfsas_hw.envs.warmstart import _discounted, demonstrations
from rfsas_hw.errors import ConfigError

CONFIG = preset("protocol").apply(EnvConfig())
THRESHOLD = CONFIG.risk_threshold


def _obs(speed: float, risk: float, warned: float = 1.0) -> np.ndarray:
    """An observation 50 m out at ``speed`` (fraction of the limit) with estimated ``risk``."""
    log_risk = (np.log10(max(risk, 1e-4)) + 4.0) / 4.0
    p_collision = min(risk * 10, 1.0)
    obs = [0.5, speed, risk, log_risk, p_collision, warned, 0.2]
    if CONFIG.observe_drive_on:  # driving on: the same risk as at the car's speed
        obs += [log_risk, p_collision]
    return np.array(obs, np.float32)


def test_the_resuming_rule_drives_on_after_a_stop_and_brakes_like_the_rule() -> None:
    rule, resuming = RulePolicy(THRESHOLD), RulePolicy(THRESHOLD, resume=True)
    stopped = _obs(0.0, 0.0)
    assert rule.act(stopped) == COAST  # the rule as evaluated: a stopped car stays stopped
    assert resuming.act(stopped) == ACCELERATE
    danger = _obs(0.8, 0.05)
    assert rule.act(danger) == resuming.act(danger) == BRAKE


def test_returns_are_discounted_from_the_end() -> None:
    assert _discounted([1.0, 1.0, 1.0], 0.5) == [1.75, 1.5, 1.0]
    assert _discounted([], 0.9) == []


def test_demonstrations_label_every_state_with_the_teacher() -> None:
    teacher = RulePolicy(THRESHOLD, resume=True)
    demo = demonstrations(teacher, 6, config=CONFIG, seed=3, explore=0.5)
    assert demo.episodes == 6 and demo.steps == len(demo.obs) == len(demo.returns)
    assert [teacher.act(o) for o in demo.obs] == demo.actions.tolist()
    again = demonstrations(teacher, 6, config=CONFIG, seed=3, explore=0.5)
    np.testing.assert_array_equal(demo.obs, again.obs)
    other = demonstrations(teacher, 6, config=CONFIG, seed=4, explore=0.5)
    assert len(other.obs) != len(demo.obs) or not np.array_equal(other.obs, demo.obs)
    # without exploration the teacher drives, and a timeout-free episode ends crossed
    quiet = demonstrations(teacher, 2, config=CONFIG, seed=3, explore=0.0)
    assert quiet.steps < 2 * CONFIG.max_steps


def test_demonstrations_stop_at_the_step_cap_between_episodes() -> None:
    teacher = RulePolicy(THRESHOLD, resume=True)
    demo = demonstrations(teacher, 50, config=CONFIG, seed=1, max_steps=10)
    assert demo.episodes == 1  # the first episode always runs, and is never cut short
    assert demo.steps > 10


@pytest.mark.parametrize(
    ("kw", "what"),
    [({"explore": 1.5}, "explore"), ({"gamma": 0.0}, "gamma"), ({"episodes": 0}, "episode")],
)
def test_bad_demonstration_arguments_are_refused(kw: dict[str, float], what: str) -> None:
    args = {"episodes": 1, **kw}
    episodes = int(args.pop("episodes"))
    with pytest.raises(ConfigError, match=what):
        demonstrations(RulePolicy(THRESHOLD), episodes, config=CONFIG, **args)


def test_cloning_makes_a_fresh_ppo_policy_act_like_the_rule() -> None:
    pytest.importorskip("stable_baselines3", reason="stable-baselines3 is not installed (make rl)")
    import torch
    from stable_baselines3 import PPO

    from rfsas_hw.envs.warmstart import clone

    torch.set_num_threads(1)
    env = IntersectionEnv(CONFIG)
    model = PPO("MlpPolicy", env, seed=0, device="cpu", gamma=0.999)
    teacher = RulePolicy(THRESHOLD, resume=True)
    demo = demonstrations(teacher, 30, config=CONFIG, seed=0, gamma=0.999)

    def agreement() -> float:
        with torch.no_grad():
            logits = model.policy.get_distribution(torch.as_tensor(demo.obs)).distribution.logits
        return float((logits.argmax(-1).numpy() == demo.actions).mean())

    before = agreement()
    stats = clone(model.policy, demo, seed=0)
    assert stats.agreement == pytest.approx(agreement())
    assert stats.agreement > 0.9 > before
    assert stats.value_rmse < float(np.std(demo.returns))  # the critic learned something
    # it drives on from a standstill and brakes in danger, states it was not shown
    actions = [int(model.predict(_obs(s, r), deterministic=True)[0]) for s, r in
               ((0.0, 0.0), (0.1, 0.0), (0.5, 0.2), (0.9, 0.3))]  # fmt: skip
    assert actions == [ACCELERATE, ACCELERATE, BRAKE, BRAKE]
    env.close()
    with pytest.raises(ConfigError, match="smoothing"):
        clone(model.policy, demo, smoothing=1.0)


def test_training_counts_the_warm_start_in_its_budget(tmp_path: Path) -> None:
    pytest.importorskip("stable_baselines3", reason="stable-baselines3 is not installed (make rl)")
    from rfsas_hw.envs.rl import train

    seen: list[int] = []
    result = train(
        4096, tmp_path / "m.zip", config=CONFIG, seed=2, log_dir=tmp_path / "logs",
        n_envs=2, n_steps=64, batch_size=64, warm_start_episodes=200,
        progress=lambda done, total: seen.append(done),
    )  # fmt: skip
    # 200 episodes would take far more than a quarter of 4096 steps: fewer ran
    assert 0 < result.warm_start_steps <= 1024 + CONFIG.max_steps
    assert result.agreement > 0.5
    with (tmp_path / "logs" / "progress.csv").open() as fh:
        ppo_steps = int(list(csv.DictReader(fh))[-1]["time/total_timesteps"])
    assert result.steps == ppo_steps + result.warm_start_steps
    assert ppo_steps >= 4096 - result.warm_start_steps
    assert seen[0] == result.warm_start_steps and seen == sorted(seen)
    with pytest.raises(ConfigError, match="warm_start_episodes"):
        train(64, tmp_path / "x.zip", config=CONFIG, warm_start_episodes=-1)
