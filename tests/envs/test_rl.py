"""PPO training, the learned-vs-rule evaluation, its risk reduction, videos and the CLI."""

from __future__ import annotations

import contextlib
import csv
import io
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chisquare

pytest.importorskip("gymnasium", reason="needs the sim extra: pip install 'rfsas-hw[sim]'")

from rfsas_hw.cli.main import main
from rfsas_hw.envs.env import ACCELERATE, BRAKE, OBS_SIZE, IntersectionEnv
from rfsas_hw.envs.rl import (
    CSV_COLUMNS,
    EvalRow,
    HoldPolicy,
    RandomPolicy,
    RulePolicy,
    evaluate,
    parse_distances,
    plot,
    record_episode,
    risk_reduction,
    run_episode,
    write_csv,
)
from rfsas_hw.errors import ConfigError, DataFormatError

TRAIN_STEPS = 1536


def rfsas(*args: str) -> tuple[int, str]:
    """Run the ``rfsas`` command line; exit code and everything it printed."""
    out = io.StringIO()
    code = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        try:
            main(list(args))
        except SystemExit as done:
            code = int(done.code or 0)
    return code, out.getvalue()


@pytest.fixture(scope="module")
def model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A short PPO run through the CLI (the method.md §10 set-up, ``--preset method``)."""
    pytest.importorskip("stable_baselines3", reason="stable-baselines3 is not installed (make rl)")
    out = tmp_path_factory.mktemp("rl") / "model.zip"
    args = ("sim", "train", "--steps", str(TRAIN_STEPS), "--preset", "method", "-o", str(out))
    code, output = rfsas(*args)
    assert code == 0, output
    assert f"trained {TRAIN_STEPS} steps" in output
    return out


def test_training_writes_the_model_and_csv_logs(model: Path) -> None:
    assert model.is_file()
    logs = model.with_name("model-logs")
    with (logs / "progress.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert int(rows[-1]["time/total_timesteps"]) == TRAIN_STEPS
    assert "train/value_loss" in rows[0]
    monitor = (logs / "monitor.csv").read_text().splitlines()
    assert monitor[1].startswith("r,l,t,collision")
    assert len(monitor) > 10
    assert not list(logs.glob("events.out.tfevents*"))


def test_short_training_gives_a_policy_that_is_not_random(model: Path) -> None:
    """After a short run the policy's actions are far from uniform and earn more reward."""
    from rfsas_hw.envs.rl import LearnedPolicy

    learned = LearnedPolicy.load(model)
    env = IntersectionEnv()
    counts = np.zeros(3)
    earned = {"learned": 0.0, "random": 0.0}
    steps = {"learned": 0, "random": 0}
    for name, policy in (("learned", learned), ("random", RandomPolicy(seed=1))):
        for seed in range(8):
            obs, _ = env.reset(seed=100 + seed)
            done = False
            while not done:
                a = policy.act(obs)
                if name == "learned":
                    counts[a] += 1
                obs, r, term, trunc, _ = env.step(a)
                earned[name] += float(r)
                steps[name] += 1
                done = term or trunc
    assert chisquare(counts).pvalue < 1e-6
    assert earned["learned"] / steps["learned"] > earned["random"] / steps["random"] + 0.2


def test_rule_brakes_only_above_the_threshold() -> None:
    rule = RulePolicy(0.01)
    obs = np.zeros(OBS_SIZE, np.float32)
    obs[2] = 0.02
    assert rule.act(obs) == BRAKE
    obs[2] = 0.005
    assert rule.act(obs) != BRAKE and rule.act(obs) != ACCELERATE


def test_evaluation_rule_beats_holding_speed_and_rows_are_consistent() -> None:
    rows = evaluate([HoldPolicy(), RulePolicy(0.0015)], [40.0, 90.0], 24)
    by = {(r.distance_m, r.policy): r for r in rows}
    # holding speed ignores the warning: the same outcome at every distance
    assert by[(40.0, "hold")] == EvalRow(**{**by[(90.0, "hold")].__dict__, "distance_m": 40.0})
    assert by[(40.0, "hold")].collisions > 3
    for r in rows:
        if r.collisions:
            assert r.risk == pytest.approx(r.p_collision * r.p_fatality)
        else:
            assert r.risk == 0.0 and math.isnan(r.p_fatality)
    assert by[(90.0, "rule")].risk < 0.2 * by[(90.0, "hold")].risk
    # an earlier warning does not make the rule worse
    assert by[(90.0, "rule")].risk <= by[(40.0, "rule")].risk


def test_an_episode_reports_its_return() -> None:
    env = IntersectionEnv({"reward": {"kind": "risk-progress"}})
    for seed in range(6):
        info = run_episode(env, HoldPolicy(), seed=seed, distance_m=50.0)
        covered = (env.front_y_m + 100.0) / 100.0
        expected = covered - 0.1 * 0.1 * info["steps"] - 50.0 * info["realised_risk"]
        assert info["return"] == pytest.approx(expected)
    rows = evaluate([HoldPolicy()], [50.0], 6, config=env.config, seed=0)
    assert rows[0].mean_return < 1.05


def test_same_episodes_for_every_policy() -> None:
    env = IntersectionEnv()
    a = run_episode(env, HoldPolicy(), seed=7, distance_m=50.0)
    b = run_episode(env, HoldPolicy(), seed=7, distance_m=50.0)
    assert a == b


def row(d: float, policy: str, risk: float, n: int = 10) -> EvalRow:
    return EvalRow(d, policy, n, 1, 0.1, risk * 10, risk, 0.0, 5.0)


def test_relative_risk_reduction_is_one_minus_the_ratio_and_pools_sums() -> None:
    rows = [
        row(40, "learned", 0.02),
        row(40, "rule", 0.08),
        row(60, "learned", 0.03),
        row(60, "rule", 0.02),
        row(80, "learned", 0.0),
        row(80, "rule", 0.0),
    ]
    per, pooled = risk_reduction(rows)
    assert per[40] == pytest.approx(0.75)
    assert per[60] == pytest.approx(-0.5)
    assert math.isnan(per[80])
    # pooled over the summed risks, not the mean of the ratios
    assert pooled == pytest.approx(1 - 0.05 / 0.10)


def test_parse_distances() -> None:
    assert parse_distances("40:100:10") == [40, 50, 60, 70, 80, 90, 100]
    assert parse_distances("40,55") == [40, 55]
    for bad in ("40:100", "a:b:c", "40:100:0", "-5", ""):
        with pytest.raises(ConfigError):
            parse_distances(bad)


def test_csv_and_plot(tmp_path: Path) -> None:
    rows = [row(40, "learned", 0.02), row(40, "rule", 0.08)]
    rows.append(EvalRow(60, "rule", 10, 0, 0.0, math.nan, 0.0, 0.0, 5.0))
    write_csv(rows, tmp_path / "eval.csv")
    lines = (tmp_path / "eval.csv").read_text().splitlines()
    assert lines[0] == ",".join(CSV_COLUMNS)
    assert lines[1] == "40,learned,0.1,0.2,0.02"
    assert lines[3] == "60,rule,0,nan,0"
    plot(rows, tmp_path / "eval.png")
    assert (tmp_path / "eval.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_gif_of_one_episode(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    from PIL import Image

    out = tmp_path / "episode.gif"
    info = record_episode(RulePolicy(0.0015), out, distance_m=60.0, seed=3)
    with Image.open(out) as gif:
        assert getattr(gif, "n_frames", 1) > 20
        assert gif.size == (550, 600)
    assert info["t_s"] > 2.0
    if shutil.which("ffmpeg") is None:
        with pytest.raises(ConfigError, match="ffmpeg"):
            record_episode(RulePolicy(0.0015), tmp_path / "episode.mp4", distance_m=60.0)
    with pytest.raises(ConfigError, match=r"\.gif or \.mp4"):
        record_episode(RulePolicy(0.0015), tmp_path / "episode.avi")


def test_cli_evaluate_and_render(
    model: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    out_csv = tmp_path / "eval.csv"
    out_png = tmp_path / "eval.png"
    args = ["sim", "evaluate", "--model", str(model), "--distances", "40,80", "--episodes", "3"]
    # the model was trained with --preset method: the default preset observes more
    code, output = rfsas(*args)
    assert code == 2 and "--preset" in output
    args += ["--preset", "method", "--scenario", "corners"]
    code, output = rfsas(*args, "--csv", str(out_csv), "--plot", str(out_png))
    assert code == 0, output
    assert "risk reduction" in output and "paired" in output and "difference" in output
    # one line says whether learned ≤ rule holds at every distance
    verdict = [line for line in output.splitlines() if "at every distance (40–80 m)" in line]
    assert len(verdict) == 1 and verdict[0].rstrip().endswith(("yes", "m)"))
    # a model is judged in the environment it was trained in
    code, output = rfsas(*args, "--prior", "on")
    assert code == 2 and "--prior" in output
    with out_csv.open() as fh:
        got = list(csv.DictReader(fh))
    assert [(r["distance_m"], r["policy"]) for r in got] == [
        ("40", "learned"),
        ("40", "rule"),
        ("80", "learned"),
        ("80", "rule"),
    ]
    assert out_png.is_file()
    # the return column follows --reward; risk and collisions do not depend on it
    code, output = rfsas(*args, "--reward", "risk-progress")
    assert code == 0, output
    assert "return" in output and "risk-progress" in output
    gif = tmp_path / "ep.gif"
    render = ["sim", "render", "--model", str(model), "--distance", "60", "-o", str(gif)]
    code, output = rfsas(*render)
    assert code == 2 and "--preset" in output and not gif.exists()
    code, output = rfsas(*render, "--preset", "method")
    assert code == 0, output
    assert "learned policy" in output and gif.is_file()


def test_cli_rejects_a_file_that_is_not_a_model(tmp_path: Path) -> None:
    pytest.importorskip("stable_baselines3", reason="stable-baselines3 is not installed (make rl)")
    from rfsas_hw.envs.rl import LearnedPolicy

    bogus = tmp_path / "model.zip"
    bogus.write_bytes(b"not a zip")
    with pytest.raises(DataFormatError, match="not a PPO model"):
        LearnedPolicy.load(bogus)
    code, output = rfsas("sim", "evaluate", "--model", str(bogus))
    assert code == 2
    assert "error:" in output and "not a PPO model" in output
