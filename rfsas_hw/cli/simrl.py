"""``rfsas sim train | evaluate | render``: learning to brake (method.md §10).

Thin shells over :mod:`rfsas_hw.envs.rl`; the library (and with it gymnasium,
pygame and stable-baselines3) is imported only when a command runs.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

if TYPE_CHECKING:
    from rfsas_hw.envs.envconfig import EnvConfig
    from rfsas_hw.envs.rl import EvalRow

_config_option = click.option(
    "--config",
    "config_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Environment configuration (YAML; unknown keys are errors).",
)
_detail_option = click.option(
    "--detail",
    type=click.Choice(["low", "medium", "high"]),
    default=None,
    help="Level of detail of the obstacle's location (default: the config's, low).",
)


def _env_config(
    config_path: Path | None, detail: str | None, reward: str | None = None
) -> EnvConfig:
    from rfsas_hw.envs.envconfig import EnvConfig, load_env_config

    config = load_env_config(config_path) if config_path is not None else EnvConfig()
    if detail is not None:
        config = dataclasses.replace(
            config,
            sensing=dataclasses.replace(config.sensing, detail=detail),  # type: ignore[arg-type]
        )
    if reward is not None:
        config = dataclasses.replace(
            config,
            reward=dataclasses.replace(config.reward, kind=reward),  # type: ignore[arg-type]
        )
    return config


@click.command()
@click.option(
    "--steps",
    type=click.IntRange(min=1),
    default=40_000,
    show_default=True,
    help="Environment steps to train.",
)
@click.option(
    "-o",
    "--output",
    "model_path",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="Where to save the model (zip).",
)
@click.option(
    "--logs",
    "log_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Directory for progress.csv and monitor.csv [default: MODEL-logs].",
)
@click.option("--seed", type=int, default=0, show_default=True, help="PPO and environment seed.")
@click.option(
    "--reward",
    type=click.Choice(["method", "risk-progress"]),
    default=None,
    help="Reward (default: the config's, method).",
)
@_config_option
@_detail_option
def train(
    steps: int,
    model_path: Path,
    log_dir: Path | None,
    seed: int,
    reward: str | None,
    config_path: Path | None,
    detail: str | None,
) -> None:
    """Train a PPO agent (MlpPolicy, seed 0, batch 64, n_steps 64, lr 3e-4) to brake."""
    from rfsas_hw.envs import rl

    config = _env_config(config_path, detail, reward)
    logs = log_dir if log_dir is not None else model_path.with_name(model_path.stem + "-logs")
    columns = (
        TextColumn("training"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total} steps"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    with Progress(*columns, transient=True) as bar:
        task = bar.add_task("train", total=steps)

        def progress(done: int, total: int) -> None:
            bar.update(task, completed=done)

        result = rl.train(
            steps, model_path, config=config, seed=seed, log_dir=logs, progress=progress
        )
    console = Console()
    console.print(
        f"trained {result.steps} steps ({result.episodes} episodes) in {result.seconds:.1f} s "
        f"({result.steps / max(result.seconds, 1e-9):.0f} steps/s), "
        f"detail {config.sensing.detail}, reward {config.reward.kind}"
    )
    console.print(f"model: {result.model_path}")
    console.print(f"logs:  {logs / 'progress.csv'}, {logs / 'monitor.csv'}")


def _fmt(x: float, digits: int = 3) -> str:
    return "—" if math.isnan(x) else f"{x:.{digits}f}"


def _table(rows: list[EvalRow], per: dict[float, float], pooled: float, names: list[str]) -> Table:
    table = Table(title="learned vs rule-based braking, by reaction distance")
    table.add_column("distance\n(m)", justify="right")
    for name in names:
        for col in ("P(coll)", "P_f", "risk"):
            table.add_column(f"{name}\n{col}", justify="right")
    table.add_column("risk\nreduction", justify="right")
    by = {(r.distance_m, r.policy): r for r in rows}
    for d in sorted({r.distance_m for r in rows}):
        cells = [f"{d:g}"]
        for name in names:
            r = by[(d, name)]
            cells += [_fmt(r.p_collision, 2), _fmt(r.p_fatality), _fmt(r.risk, 4)]
        cells.append("—" if math.isnan(per.get(d, math.nan)) else f"{per[d]:+.0%}")
        table.add_row(*cells)
    total = "—" if math.isnan(pooled) else f"{pooled:+.0%}"
    table.caption = (
        f"risk reduction = 1 − risk(learned)/risk(rule); over all distances: {total}. "
        "P_f is the mean fatality risk of the collisions."
    )
    return table


@click.command()
@click.option(
    "--model",
    "model_path",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="Model saved by rfsas sim train.",
)
@click.option(
    "--distances",
    default="40:100:10",
    show_default=True,
    help="Reaction distances in metres: start:stop:step (stop included) or a list.",
)
@click.option(
    "--episodes",
    type=click.IntRange(min=1),
    default=200,
    show_default=True,
    help="Episodes per policy and distance.",
)
@click.option(
    "--seed",
    type=int,
    default=10_000,
    show_default=True,
    help="Seed of the first episode (both policies see the same episodes).",
)
@click.option(
    "--threshold",
    type=float,
    default=None,
    help="Risk threshold of the rule [default: the config's].",
)
@click.option(
    "--csv",
    "csv_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Write distance_m,policy,p_collision,p_fatality,risk here.",
)
@click.option(
    "--plot",
    "plot_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Draw the three measures against distance (PNG).",
)
@_config_option
@_detail_option
def evaluate(
    model_path: Path,
    distances: str,
    episodes: int,
    seed: int,
    threshold: float | None,
    csv_path: Path | None,
    plot_path: Path | None,
    config_path: Path | None,
    detail: str | None,
) -> None:
    """Compare the learned policy with the rule (brake above the risk threshold, else hold)."""
    from rfsas_hw.envs import rl

    config = _env_config(config_path, detail)
    dists = rl.parse_distances(distances)
    learned = rl.LearnedPolicy.load(model_path)
    rule = rl.RulePolicy(config.risk_threshold if threshold is None else threshold)
    rows = rl.evaluate([learned, rule], dists, episodes, config=config, seed=seed)
    per, pooled = rl.risk_reduction(rows)
    Console().print(_table(rows, per, pooled, ["learned", "rule"]))
    if csv_path is not None:
        rl.write_csv(rows, csv_path)
        click.echo(f"wrote {csv_path}")
    if plot_path is not None:
        rl.plot(rows, plot_path)
        click.echo(f"wrote {plot_path}")


@click.command()
@click.option(
    "--model",
    "model_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Model saved by rfsas sim train [default: the rule policy].",
)
@click.option(
    "--distance",
    type=click.FloatRange(min=0),
    default=None,
    help="Reaction distance, metres [default: drawn as in training].",
)
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="Video file: .gif, or .mp4 when ffmpeg is installed.",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Episode seed.")
@_config_option
@_detail_option
def render(
    model_path: Path | None,
    distance: float | None,
    output: Path,
    seed: int,
    config_path: Path | None,
    detail: str | None,
) -> None:
    """Render one episode of the learned (or rule) policy to a video."""
    from rfsas_hw.envs import rl

    config = _env_config(config_path, detail)
    policy: Any = (
        rl.LearnedPolicy.load(model_path)
        if model_path is not None
        else rl.RulePolicy(config.risk_threshold)
    )
    info = rl.record_episode(policy, output, distance_m=distance, config=config, seed=seed)
    if info["collision"]:
        outcome = f"collision at {info['impact_speed_mps'] * 3.6:.0f} km/h"
    elif info["speed_mps"] == 0:
        outcome = f"stopped {info['distance_m']:.1f} m before the centre"
    else:
        outcome = f"no collision, crossed at {info['speed_mps'] * 3.6:.0f} km/h"
    click.echo(f"wrote {output}: {policy.name} policy, {info['t_s']:.1f} s, {outcome}")
