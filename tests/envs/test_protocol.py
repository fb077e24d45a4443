"""The multi-seed protocol: reproducible training, paired statistics, speed profiles, CLI."""

from __future__ import annotations

import contextlib
import io
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("gymnasium", reason="needs the sim extra: pip install 'rfsas-hw[sim]'")

from rfsas_hw.cli.main import main
from rfsas_hw.envs.env import BRAKE
from rfsas_hw.envs.envconfig import EnvConfig, env_config_from_mapping
from rfsas_hw.envs.protocol import (
    Outcomes,
    cannot_stop,
    compare,
    eval_rows,
    not_holding,
    outcomes,
    pooled_ratio,
    seed_model_path,
    speed_profiles,
)
from rfsas_hw.envs.rl import HoldPolicy, RulePolicy
from rfsas_hw.errors import ConfigError

CORNERS = {"scenario": {"kind": "corners"}, "prior": {"observe": True}}


def rfsas(*args: str) -> tuple[int, str]:
    out = io.StringIO()
    code = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        try:
            main(list(args))
        except SystemExit as done:
            code = int(done.code or 0)
    return code, out.getvalue()


def fake(risks: list[list[float]]) -> Outcomes:
    r = np.array(risks)
    return Outcomes((40.0, 60.0)[: len(r)], r, r > 0, np.full(r.shape, 5.0), r == 0)


def test_compare_pairs_the_episodes_and_pools() -> None:
    base = fake([[0.1, 0.0, 0.2, 0.1], [0.0, 0.0, 0.0, 0.0]])
    a = fake([[0.0, 0.0, 0.1, 0.0], [0.0, 0.0, 0.0, 0.0]])
    b = fake([[0.1, 0.0, 0.0, 0.1], [0.0, 0.0, 0.0, 0.0]])
    rows = compare([a, b], base)
    r40, r60 = rows
    assert r40.risk == pytest.approx(0.0375) and r40.baseline_risk == pytest.approx(0.1)
    # per-seed means 0.025 and 0.05: standard error of two values
    assert r40.risk_se_seeds == pytest.approx(np.std([0.025, 0.05], ddof=1) / math.sqrt(2))
    assert r40.seeds_at_or_below == 2 and r40.p_collision == pytest.approx(3 / 8)
    assert 0 < r40.p_value < 1
    assert r60.p_value == 1.0 and r60.risk == 0.0
    assert pooled_ratio(rows, [40.0]) == pytest.approx(0.1 / 0.0375)
    assert math.isnan(pooled_ratio(rows, [60.0]))
    with pytest.raises(ConfigError, match="same distances"):
        compare([fake([[0.0]])], base)


def test_a_difference_without_spread_is_certain_and_warns_nothing() -> None:
    # the same nonzero difference in every episode: t is infinite, p is 0 (scipy would warn
    # of lost precision, an error under this suite's warning filter)
    base = fake([[0.1, 0.2, 0.3, 0.4]])
    rows = compare([fake([[0.05, 0.15, 0.25, 0.35]])], base)
    assert rows[0].p_value == 0.0
    # with any spread the paired test decides
    rows = compare([fake([[0.05, 0.15, 0.25, 0.36]])], base)
    assert 0 < rows[0].p_value < 1


class StopPolicy:
    """Brakes from the first step and stays stopped: the degenerate exit."""

    name = "stop"

    def act(self, obs: Any) -> int:
        return BRAKE


def test_a_policy_that_always_stops_does_not_score_as_safe() -> None:
    # A parked car hits nobody, so its collision risk is 0 and risk alone would call it
    # safer than the rule; but it never arrives: every episode times out, and the
    # verdict counts that against it.
    config = env_config_from_mapping({"reward": {"kind": "risk-progress"}, "max_steps": 120})
    stop = outcomes(StopPolicy(), [60.0, 90.0], 3, config=config)
    rule = outcomes(RulePolicy(0.0015), [60.0, 90.0], 3, config=config)
    assert stop.risk.sum() == 0.0 and stop.timeouts.all()
    assert not rule.timeouts.any() and rule.crossed.any()
    rows = compare([stop], rule)
    assert all(r.risk <= r.baseline_risk for r in rows)  # the risk alone would pass it
    assert all(r.timeouts == 1.0 and r.baseline_timeouts == 0.0 for r in rows)
    assert not any(r.holds for r in rows)
    assert not_holding(rows) == [60.0, 90.0]
    # and training pays it less than the rule: time and the timeout cost
    assert all(r.mean_return < r.baseline_return for r in rows)
    summary = eval_rows(stop, "stop")
    assert [s.timeouts for s in summary] == [1.0, 1.0]
    assert [s.risk for s in summary] == [0.0, 0.0]


def test_learned_holds_within_one_standard_error_of_the_paired_difference() -> None:
    base = fake([[0.1, 0.0, 0.0, 0.0], [0.1, 0.0, 0.0, 0.0]])
    # 40 m: 0.025 above the rule, within the SE of the difference (0.048); 60 m: 0.075
    # above it, beyond its SE (0.025)
    learned = fake([[0.0, 0.1, 0.1, 0.0], [0.1, 0.1, 0.1, 0.1]])
    r40, r60 = compare([learned], base)
    assert r40.difference_se == pytest.approx(np.std([-0.1, 0.1, 0.1, 0], ddof=1) / 2)
    assert r40.risk - r40.baseline_risk == pytest.approx(0.025)
    assert r60.risk - r60.baseline_risk > r60.difference_se
    assert r40.holds and not r60.holds
    assert not_holding([r40, r60]) == [60.0]
    assert not_holding(compare([base], base)) == []


def test_the_rule_cannot_stop_only_from_close() -> None:
    config = EnvConfig()
    assert cannot_stop(config, 30.0) and cannot_stop(config, 40.0)
    assert not cannot_stop(config, 50.0)


def test_outcomes_use_the_same_episodes_for_every_policy() -> None:
    config = env_config_from_mapping(CORNERS)
    a = outcomes(RulePolicy(0.0015), [40.0, None], 6, config=config)
    b = outcomes(RulePolicy(0.0015), [40.0, None], 6, config=config)
    np.testing.assert_array_equal(a.risk, b.risk)
    h = outcomes(HoldPolicy(), [40.0], 6, config=config)
    assert h.risk.sum() >= a.risk[0].sum()
    assert math.isnan(a.distances_m[1])


def test_speed_profile_without_a_warning() -> None:
    config = env_config_from_mapping(CORNERS)
    grid, speed = speed_profiles(
        RulePolicy(0.0015), 3, config=config, options={"crosser": False, "corner": "busy"}
    )
    assert grid[0] == 100.0 and grid[-1] == 0.0
    np.testing.assert_allclose(speed, 20.0)  # no warning: the rule never brakes


def test_training_is_reproducible_per_seed(tmp_path: Path) -> None:
    pytest.importorskip("stable_baselines3", reason="stable-baselines3 is not installed (make rl)")
    from stable_baselines3 import PPO

    from rfsas_hw.envs.protocol import train_seeds

    config = env_config_from_mapping({**CORNERS, "reward": {"kind": "risk-progress"}})
    kw: dict[str, Any] = {"config": config, "n_envs": 2, "n_steps": 32, "batch_size": 32}
    a = train_seeds([5], 128, tmp_path / "a.zip", **kw)[0]
    b = train_seeds([5], 128, tmp_path / "b.zip", **kw)[0]
    c = train_seeds([6], 128, tmp_path / "c.zip", **kw)[0]
    assert a.model_path == seed_model_path(tmp_path / "a.zip", 5)
    pa, pb, pc = (PPO.load(str(r.model_path), device="cpu").policy.state_dict() for r in (a, b, c))
    assert all(np.array_equal(pa[k].numpy(), pb[k].numpy()) for k in pa)
    assert not all(np.array_equal(pa[k].numpy(), pc[k].numpy()) for k in pa)
    assert (a.model_path.with_name("a-seed-5-logs") / "env-1.monitor.csv").is_file()


def test_cli_trains_and_evaluates_several_seeds(tmp_path: Path) -> None:
    pytest.importorskip("stable_baselines3", reason="stable-baselines3 is not installed (make rl)")
    model = tmp_path / "m.zip"
    common = ("--prior", "on", "--scenario", "corners")
    code, out = rfsas(
        "sim", "train", "--steps", "64", "--seeds", "0,1", "--envs", "2",
        "--reward", "risk-progress", "--n-steps", "32", "--batch-size", "32",
        "--ent-coef", "0.01", "-o", str(model), *common,
    )  # fmt: skip
    assert code == 0, out
    assert "seed 0: trained" in out and "seed 1: trained" in out and "prior on" in out
    assert seed_model_path(model, 1).is_file()
    from rfsas_hw.envs.rl import LearnedPolicy

    ppo = LearnedPolicy.load(seed_model_path(model, 0)).model
    assert (ppo.n_steps, ppo.batch_size, ppo.ent_coef) == (32, 32, 0.01)
    code, out = rfsas(
        "sim", "evaluate", "--model", str(model), "--seeds", "0,1",
        "--distances", "40,60", "--episodes", "3", *common,
    )  # fmt: skip
    assert code == 0, out
    assert "(2 seeds)" in out and "cannot stop" in out
    code, out = rfsas(
        "sim", "evaluate", "--model", str(model), "--seeds", "0,1", "--episodes", "1",
        "--prior", "off",
    )  # fmt: skip
    assert code == 2 and "--prior" in out
    code, out = rfsas(
        "sim", "evaluate", "--model", str(model), "--seeds", "0", "--csv", str(tmp_path / "x.csv"),
    )  # fmt: skip
    assert code == 2 and "--seeds" in out
    code, out = rfsas("sim", "train", "--seeds", "1,1", "-o", str(model))
    assert code == 2 and "distinct" in out


def test_cli_defaults_train_the_protocol_configuration(tmp_path: Path) -> None:
    pytest.importorskip("stable_baselines3", reason="stable-baselines3 is not installed (make rl)")
    from rfsas_hw.envs.presets import PRESETS
    from rfsas_hw.envs.rl import PPO_DEFAULTS, LearnedPolicy

    model = tmp_path / "m.zip"
    code, out = rfsas("sim", "train", "--steps", "64", "-o", str(model))
    assert code == 0, out
    assert "preset protocol" in out and "reward risk-progress" in out
    assert "scenario corners" in out and "prior off" in out
    ppo = LearnedPolicy.load(model).model
    assert (ppo.n_envs, ppo.n_steps, ppo.batch_size, ppo.ent_coef) == (8, 128, 256, 0.01)
    assert ppo.gamma == 0.99 and "discount 0.99" in out and "warm start" not in out
    assert PRESETS["protocol"].steps <= 150_000  # the documented budget of a few minutes
    # the method's settings are one option away
    model = tmp_path / "method.zip"
    code, out = rfsas("sim", "train", "--steps", "64", "--preset", "method", "-o", str(model))
    assert code == 0, out
    assert "reward method" in out and "scenario single" in out
    ppo = LearnedPolicy.load(model).model
    assert (ppo.n_envs, ppo.n_steps, ppo.batch_size, ppo.ent_coef) == (
        1,
        PPO_DEFAULTS["n_steps"],
        PPO_DEFAULTS["batch_size"],
        PPO_DEFAULTS["ent_coef"],
    )
    # an option given wins over the preset
    model = tmp_path / "reward.zip"
    code, out = rfsas("sim", "train", "--steps", "64", "--reward", "method", "-o", str(model))
    assert code == 0 and "preset protocol" in out and "reward method" in out
    # the warm start and the discount are options; 64 steps leave room for one episode
    model = tmp_path / "warm.zip"
    code, out = rfsas(
        "sim", "train", "--steps", "64", "--warm-start", "100", "--gamma", "0.999", "-o", str(model)
    )  # fmt: skip
    assert code == 0, out
    assert "warm start: 1 episode of the rule" in out and "discount 0.999" in out
    assert LearnedPolicy.load(model).model.gamma == 0.999
