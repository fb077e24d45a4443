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
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Table

from rfsas_hw.cli.options import out_option
from rfsas_hw.cli.outopts import OutputPath
from rfsas_hw.outpaths import check_output

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


_prior_option = click.option(
    "--prior",
    type=click.Choice(["on", "off"]),
    default=None,
    help="RF activity prior ahead of the car in the observation (default: the config's, off).",
)
_scenario_option = click.option(
    "--scenario",
    type=click.Choice(["single", "corners"]),
    default=None,
    help="Episodes: one crosser, or quiet and busy corners (default: the config's, single).",
)
_seeds_option = click.option(
    "--seeds",
    default=None,
    help="Comma list of seeds (e.g. 0,1,2,3,4): one model per seed, MODEL-seed-<s>.zip.",
)


def _parse_seeds(text: str | None) -> list[int] | None:
    if text is None:
        return None
    try:
        seeds = [int(p) for p in text.split(",") if p.strip()]
    except ValueError as err:
        raise click.BadParameter(f"{text!r}: expected a comma list of integers") from err
    if not seeds or len(set(seeds)) != len(seeds):
        raise click.BadParameter(f"{text!r}: expected distinct integers", param_hint="--seeds")
    return seeds


def _env_config(
    config_path: Path | None,
    detail: str | None,
    reward: str | None = None,
    prior: str | None = None,
    scenario: str | None = None,
) -> EnvConfig:
    from rfsas_hw.envs.envconfig import EnvConfig, load_env_config

    config = load_env_config(config_path) if config_path is not None else EnvConfig()
    if prior is not None:
        config = dataclasses.replace(
            config, prior=dataclasses.replace(config.prior, observe=prior == "on")
        )
    if scenario is not None:
        config = dataclasses.replace(
            config,
            scenario=dataclasses.replace(config.scenario, kind=scenario),  # type: ignore[arg-type]
        )
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
@out_option(
    "Where to save the model (zip).",
    dest="model_path",
    required=True,
)
@click.option(
    "--logs",
    "log_dir",
    type=OutputPath("dir"),
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
@click.option(
    "--envs",
    "n_envs",
    type=click.IntRange(min=1),
    default=1,
    show_default=True,
    help="Environments stepped side by side (vectorised, one process).",
)
@click.option(
    "--n-steps",
    type=click.IntRange(min=2),
    default=None,
    help="PPO rollout steps per environment [default: 64, the method's].",
)
@click.option(
    "--batch-size",
    type=click.IntRange(min=2),
    default=None,
    help="PPO minibatch size [default: 64, the method's].",
)
@click.option(
    "--ent-coef",
    type=click.FloatRange(min=0.0),
    default=None,
    help="PPO entropy coefficient [default: 0, the method's].",
)
@_seeds_option
@_prior_option
@_scenario_option
@_config_option
@_detail_option
def train(
    steps: int,
    model_path: Path,
    log_dir: Path | None,
    seed: int,
    reward: str | None,
    n_envs: int,
    n_steps: int | None,
    batch_size: int | None,
    ent_coef: float | None,
    seeds: str | None,
    prior: str | None,
    scenario: str | None,
    config_path: Path | None,
    detail: str | None,
) -> None:
    """Train a PPO agent (MlpPolicy, seed 0, batch 64, n_steps 64, lr 3e-4) to brake."""
    from rfsas_hw.envs import rl

    if config_path is not None:
        check_output(model_path, [config_path], force=True)
    config = _env_config(config_path, detail, reward, prior, scenario)
    given = {"n_steps": n_steps, "batch_size": batch_size, "ent_coef": ent_coef}
    ppo = {k: v for k, v in given.items() if v is not None}
    seed_list = _parse_seeds(seeds)
    if seed_list is not None:
        _train_seeds(seed_list, steps, model_path, config, n_envs, ppo)
        return
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
            steps,
            model_path,
            config=config,
            seed=seed,
            log_dir=logs,
            progress=progress,
            n_envs=n_envs,
            **ppo,
        )
    console = Console()
    console.print(
        f"trained {result.steps} steps ({result.episodes} episodes) in {result.seconds:.1f} s "
        f"({result.steps / max(result.seconds, 1e-9):.0f} steps/s), "
        f"detail {config.sensing.detail}, reward {config.reward.kind}"
    )
    console.print(f"model: {result.model_path}")
    console.print(f"logs:  {logs / 'progress.csv'}, {logs / 'monitor.csv'}")


def _train_seeds(
    seeds: list[int],
    steps: int,
    model_path: Path,
    config: EnvConfig,
    n_envs: int,
    ppo: dict[str, Any],
) -> None:
    from rfsas_hw.envs import protocol

    columns = (
        TextColumn("seed {task.fields[seed]}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total} steps"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    console = Console()
    with Progress(*columns, console=console) as bar:
        tasks = {s: bar.add_task("train", total=steps, seed=s) for s in seeds}

        def progress(s: int) -> Any:
            def update(done: int, total: int) -> None:
                bar.update(tasks[s], completed=done)

            return update

        results = protocol.train_seeds(
            seeds, steps, model_path, config=config, n_envs=n_envs, progress=progress, **ppo
        )
    for s, result in zip(seeds, results, strict=True):
        console.print(
            f"seed {s}: trained {result.steps} steps ({result.episodes} episodes) in "
            f"{result.seconds:.1f} s; model {result.model_path}"
        )
    console.print(
        f"detail {config.sensing.detail}, reward {config.reward.kind}, "
        f"prior {'on' if config.prior.observe else 'off'}, scenario {config.scenario.kind}"
    )


def _fmt(x: float, digits: int = 3) -> str:
    return "—" if math.isnan(x) else f"{x:.{digits}f}"


def _table(
    rows: list[EvalRow], per: dict[float, float], pooled: float, names: list[str], reward: str
) -> Table:
    table = Table(title="learned vs rule-based braking, by reaction distance")
    table.add_column("distance\n(m)", justify="right")
    for name in names:
        for col in ("P(coll)", "P_f", "risk", "return"):
            table.add_column(f"{name}\n{col}", justify="right")
    table.add_column("risk\nreduction", justify="right")
    by = {(r.distance_m, r.policy): r for r in rows}
    for d in sorted({r.distance_m for r in rows}):
        cells = [f"{d:g}"]
        for name in names:
            r = by[(d, name)]
            cells += [
                _fmt(r.p_collision, 2),
                _fmt(r.p_fatality),
                _fmt(r.risk, 4),
                _fmt(r.mean_return, 2),
            ]
        cells.append("—" if math.isnan(per.get(d, math.nan)) else f"{per[d]:+.0%}")
        table.add_row(*cells)
    total = "—" if math.isnan(pooled) else f"{pooled:+.0%}"
    table.caption = (
        f"risk reduction = 1 − risk(learned)/risk(rule); over all distances: {total}. "
        f"P_f is the mean fatality risk of the collisions; return: mean episode return "
        f"under the {reward} reward."
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
    type=OutputPath(),
    default=None,
    help="Write distance_m,policy,p_collision,p_fatality,risk here.",
)
@click.option(
    "--plot",
    "plot_path",
    type=OutputPath(),
    default=None,
    help="Draw the three measures against distance (PNG).",
)
@click.option(
    "--reward",
    type=click.Choice(["method", "risk-progress"]),
    default=None,
    help="Reward whose mean episode return is reported (default: the config's, method); "
    "risk and collisions do not depend on it.",
)
@_seeds_option
@_prior_option
@_scenario_option
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
    reward: str | None,
    seeds: str | None,
    prior: str | None,
    scenario: str | None,
    config_path: Path | None,
    detail: str | None,
) -> None:
    """Compare the learned policy with the rule (brake above the risk threshold, else hold)."""
    from rfsas_hw.envs import rl

    for target in (csv_path, plot_path):
        if target is not None:  # a result of an earlier run may be replaced, an input never
            check_output(target, [p for p in (model_path, config_path) if p], force=True)
    config = _env_config(config_path, detail, reward, prior=prior, scenario=scenario)
    dists = rl.parse_distances(distances)
    seed_list = _parse_seeds(seeds)
    if seed_list is not None:
        if csv_path is not None or plot_path is not None:
            raise click.UsageError("--csv and --plot are for one model, not with --seeds")
        _evaluate_seeds(model_path, seed_list, dists, episodes, seed, threshold, config)
        return
    learned = rl.LearnedPolicy.load(model_path)
    rule = rl.RulePolicy(config.risk_threshold if threshold is None else threshold)
    with _episode_bar() as bar:
        task = bar.add_task("episodes", total=None)
        rows = rl.evaluate(
            [learned, rule],
            dists,
            episodes,
            config=config,
            seed=seed,
            progress=lambda done, total: bar.update(task, completed=done, total=total),
        )
    per, pooled = rl.risk_reduction(rows)
    Console().print(_table(rows, per, pooled, ["learned", "rule"], config.reward.kind))
    if csv_path is not None:
        rl.write_csv(rows, csv_path)
        click.echo(f"wrote {csv_path}")
    if plot_path is not None:
        rl.plot(rows, plot_path)
        click.echo(f"wrote {plot_path}")


def _episode_bar() -> Progress:
    """A progress bar on stderr for simulated episodes (gone when they are done)."""
    return Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=Console(stderr=True),
        transient=True,
    )


def _evaluate_seeds(
    model_path: Path,
    seeds: list[int],
    dists: list[float],
    episodes: int,
    first: int,
    threshold: float | None,
    config: EnvConfig,
) -> None:
    from rfsas_hw.envs import protocol, rl
    from rfsas_hw.envs.env import IntersectionEnv
    from rfsas_hw.errors import ConfigError

    env = IntersectionEnv(config)
    rule = rl.RulePolicy(config.risk_threshold if threshold is None else threshold)
    learned = []
    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total} distances"),
        TimeElapsedColumn(),
    )
    with Progress(*columns, transient=True) as bar:
        for s in seeds:
            policy = rl.LearnedPolicy.load(protocol.seed_model_path(model_path, s))
            shape = policy.model.observation_space.shape
            if shape != env.observation_space.shape:
                raise ConfigError(
                    f"model of seed {s} observes {shape}, the environment gives "
                    f"{env.observation_space.shape}: pass the --prior it was trained with"
                )
            task = bar.add_task(f"seed {s}", total=len(dists))
            runs = []
            for d in dists:
                runs.append(protocol.outcomes(policy, [d], episodes, seed=first, env=env))
                bar.update(task, advance=1)
            learned.append(_join(runs))
        base = protocol.outcomes(rule, dists, episodes, seed=first, env=env)
    rows = protocol.compare(learned, base)
    start = config.vehicle.start_distance_m
    table = Table(title=f"learned ({len(seeds)} seeds) vs rule, same {episodes} episodes")
    for col in (
        "from centre\n(m)",
        "from start\n(m)",
        "learned\nrisk",
        "± SE\nseeds",
        "rule\nrisk",
        "± SE",
        "paired\np",
        "seeds\n≤ rule",
        "learned\nreturn",
        "rule\nreturn",
        "learned\ntimeouts",
    ):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(
            f"{r.distance_m:g}",
            f"{start - r.distance_m:g}",
            f"{r.risk:.4f}",
            _fmt(r.risk_se_seeds, 4),
            f"{r.baseline_risk:.4f}",
            _fmt(r.baseline_se, 4),
            f"{r.p_value:.3g}",
            f"{r.seeds_at_or_below}/{r.seeds}",
            _fmt(r.mean_return, 2),
            _fmt(r.baseline_return, 2),
            f"{r.timeouts:.0%}",
        )
    stop = [d for d in dists if protocol.cannot_stop(config, d)]
    ratio = protocol.pooled_ratio(rows, stop)
    table.caption = (
        f"rule/learned pooled risk where the rule cannot stop ({', '.join(f'{d:g}' for d in stop)}"
        f" m): {ratio:.2f}"
        if stop
        else "the rule can stop at every distance"
    )
    Console().print(table)


def _join(runs: list[Any]) -> Any:
    import numpy as np

    from rfsas_hw.envs.protocol import Outcomes

    return Outcomes(
        tuple(d for r in runs for d in r.distances_m),
        np.concatenate([r.risk for r in runs]),
        np.concatenate([r.collision for r in runs]),
        np.concatenate([r.time_s for r in runs]),
        np.concatenate([r.crossed for r in runs]),
        np.concatenate([r.returns for r in runs]),
    )


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
@out_option(
    "Video file: .gif, or .mp4 when ffmpeg is installed.",
    dest="output",
    required=True,
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

    check_output(output, [p for p in (model_path, config_path) if p], force=True)
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
