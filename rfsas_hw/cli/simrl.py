"""``rfsas sim train | evaluate | render``: learning to brake (method.md §10).

Thin shells over :mod:`rfsas_hw.envs.rl`; the library (and with it gymnasium,
pygame and stable-baselines3) is imported only when a command runs.
"""

from __future__ import annotations

import dataclasses
import math
import sys
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

from rfsas_hw.cli.options import out_option, runner_options
from rfsas_hw.cli.outopts import OutputPath
from rfsas_hw.outpaths import check_output

if TYPE_CHECKING:
    from rfsas_hw.envs.envconfig import EnvConfig
    from rfsas_hw.envs.protocol import PairedRow

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
    help="RF activity prior ahead of the car in the observation [default: the preset's, off].",
)
_scenario_option = click.option(
    "--scenario",
    type=click.Choice(["single", "corners"]),
    default=None,
    help="Episodes: one crosser, or quiet and busy corners "
    "[default: the preset's; protocol corners, method single].",
)
_preset_option = click.option(
    "--preset",
    type=click.Choice(["protocol", "method"]),
    default="protocol",
    show_default=True,
    help="protocol: the risk-progress reward at quiet and busy corners, no prior, the "
    "risk of driving on observed, 8 environments, PPO n_steps 128, batch 256, entropy "
    "0.01 (learned at or below the rule in the multi-seed protocol); method: method.md "
    "§10 as written (its reward, one crosser, one environment, n_steps 64, batch 64, "
    "entropy 0). --reward, --scenario, --prior and the PPO options override it.",
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
    preset: str = "protocol",
) -> EnvConfig:
    """The configuration file (or the defaults), then the preset's reward, scenario and
    prior, then the options given."""
    from rfsas_hw.envs.envconfig import EnvConfig, load_env_config
    from rfsas_hw.envs.presets import preset as named

    config = load_env_config(config_path) if config_path is not None else EnvConfig()
    config = named(preset).apply(config)
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
    default=None,
    help="Environment steps to train, a warm start's included "
    "[default: the preset's; protocol 150000, method 40000].",
)
@click.option(
    "--warm-start",
    "warm_start",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    help="Episodes of the rule (resuming after a stop) cloned into the policy before PPO, "
    "their steps part of --steps; 0: PPO starts from a random policy.",
)
@click.option(
    "--gamma",
    type=click.FloatRange(min=0.0, max=1.0, min_open=True),
    default=None,
    help="PPO discount [default: 0.99].",
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
    help="Reward [default: the preset's; protocol risk-progress, method method].",
)
@click.option(
    "--envs",
    "n_envs",
    type=click.IntRange(min=1),
    default=None,
    help="Environments stepped side by side (vectorised, one process) "
    "[default: the preset's; protocol 8, method 1].",
)
@click.option(
    "--n-steps",
    type=click.IntRange(min=2),
    default=None,
    help="PPO rollout steps per environment [default: the preset's; protocol 128, method 64].",
)
@click.option(
    "--batch-size",
    type=click.IntRange(min=2),
    default=None,
    help="PPO minibatch size [default: the preset's; protocol 256, method 64].",
)
@click.option(
    "--ent-coef",
    type=click.FloatRange(min=0.0),
    default=None,
    help="PPO entropy coefficient [default: the preset's; protocol 0.01, method 0].",
)
@_preset_option
@_seeds_option
@runner_options(what="seeds")
@_prior_option
@_scenario_option
@_config_option
@_detail_option
def train(
    steps: int | None,
    warm_start: int,
    gamma: float | None,
    model_path: Path,
    log_dir: Path | None,
    seed: int,
    reward: str | None,
    n_envs: int | None,
    n_steps: int | None,
    batch_size: int | None,
    ent_coef: float | None,
    preset: str,
    seeds: str | None,
    workers: int | None,
    scheduler: str | None,
    prior: str | None,
    scenario: str | None,
    config_path: Path | None,
    detail: str | None,
) -> None:
    """Train a PPO agent (MlpPolicy, seed 0) to brake, with the preset's settings."""
    from rfsas_hw.envs import rl
    from rfsas_hw.envs.presets import preset as named

    if config_path is not None:
        check_output(model_path, [config_path], force=True)
    config = _env_config(config_path, detail, reward, prior, scenario, preset)
    chosen = named(preset)
    steps = chosen.steps if steps is None else steps
    n_envs = chosen.n_envs if n_envs is None else n_envs
    given = {"n_steps": n_steps, "batch_size": batch_size, "ent_coef": ent_coef, "gamma": gamma}
    ppo = {**chosen.ppo, **{k: v for k, v in given.items() if v is not None}}
    ppo["warm_start_episodes"] = warm_start
    seed_list = _parse_seeds(seeds)
    if seed_list is not None:
        _train_seeds(seed_list, steps, model_path, config, n_envs, ppo, workers, scheduler)
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
        f"({result.steps / max(result.seconds, 1e-9):.0f} steps/s), preset {preset}: "
        f"detail {config.sensing.detail}, reward {config.reward.kind}, "
        f"scenario {config.scenario.kind}, prior {'on' if config.prior.observe else 'off'}, "
        f"drive-on risk {'on' if config.observe_drive_on else 'off'}, "
        f"{n_envs} env(s), PPO n_steps {ppo['n_steps']}, batch {ppo['batch_size']}, "
        f"entropy {ppo['ent_coef']:g}, discount {ppo.get('gamma', 0.99):g}"
    )
    if result.warm_start_steps:
        console.print(
            f"warm start: {result.warm_start_episodes} "
            f"episode{'s' if result.warm_start_episodes != 1 else ''} of the rule "
            f"({result.warm_start_steps} of the steps), its action in "
            f"{result.agreement:.0%} of their states after cloning"
        )
    console.print(f"model: {result.model_path}")
    monitor = "monitor.csv" if n_envs == 1 else "env-<i>.monitor.csv"
    console.print(f"logs:  {logs / 'progress.csv'}, {logs / monitor}")


def _train_seeds(
    seeds: list[int],
    steps: int,
    model_path: Path,
    config: EnvConfig,
    n_envs: int,
    ppo: dict[str, Any],
    workers: int | None,
    scheduler: str | None,
) -> None:
    from rfsas_hw.envs import protocol
    from rfsas_hw.parallel import default_workers

    if workers is None:
        workers = default_workers(len(seeds), here=scheduler is not None)
    here = workers == 0 and scheduler is None
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

        def finished(s: int, result: Any) -> None:  # side by side: a seed's bar fills at its end
            bar.update(tasks[s], completed=steps)

        results = protocol.train_seeds(
            seeds, steps, model_path, config=config, n_envs=n_envs,
            progress=progress if here else None, on_seed=finished, workers=workers,
            scheduler=scheduler, **ppo,
        )  # fmt: skip
    for s, result in zip(seeds, results, strict=True):
        console.print(
            f"seed {s}: trained {result.steps} steps ({result.episodes} episodes) in "
            f"{result.seconds:.1f} s; model {result.model_path}"
        )
    console.print(
        f"detail {config.sensing.detail}, reward {config.reward.kind}, "
        f"prior {'on' if config.prior.observe else 'off'}, "
        f"drive-on risk {'on' if config.observe_drive_on else 'off'}, "
        f"scenario {config.scenario.kind}"
    )


def _fmt(x: float, digits: int = 3) -> str:
    return "—" if math.isnan(x) else f"{x:.{digits}f}"


def _paired_table(rows: list[PairedRow], start_m: float, title: str, reward: str) -> Table:
    """Learned against rule per distance: risks with standard errors, the paired test,
    timeouts, returns and whether learned ≤ rule holds there."""
    several = rows[0].seeds > 1
    table = Table(title=title)
    columns = [
        "from centre\n(m)",
        "from start\n(m)",
        f"learned risk\n± SE{' (seeds)' if several else ''}",
        "rule risk\n± SE",
        "difference\n± SE",
        "paired\np",
        *(["seeds\n≤ rule"] if several else []),
        "learned\ntimeouts",
        "time (s)\nlearned / rule",
        "return\nlearned / rule",
        "≤ rule",
    ]
    for col in columns:
        table.add_column(col, justify="right")
    for r in rows:
        se = r.risk_se_seeds if several else r.risk_se_episodes
        table.add_row(
            f"{r.distance_m:g}",
            f"{start_m - r.distance_m:g}",
            f"{r.risk:.4f} ± {_fmt(se, 4)}",
            f"{r.baseline_risk:.4f} ± {_fmt(r.baseline_se, 4)}",
            f"{r.risk - r.baseline_risk:+.4f} ± {_fmt(r.difference_se, 4)}",
            f"{r.p_value:.3g}",
            *([f"{r.seeds_at_or_below}/{r.seeds}"] if several else []),
            f"{r.timeouts:.0%}",
            f"{r.time_s:.1f} / {r.baseline_time_s:.1f}",
            f"{_fmt(r.mean_return, 2)} / {_fmt(r.baseline_return, 2)}",
            "yes" if r.holds else "NO",
        )
    table.caption = (
        f"risk: mean realised fatality risk per episode, SE over the "
        f"{'seeds' if several else 'episodes'} (rule: over the episodes); difference: learned "
        f"− rule over the same episodes, with the two-sided paired t-test; timeouts: episodes "
        f"that never crossed; time: mean episode duration; return under the {reward} reward"
    )
    return table


def _console() -> Console:
    """Standard output; wide enough for the tables when it is not a terminal."""
    return Console() if sys.stdout.isatty() else Console(width=160)


def _verdict(rows: list[PairedRow], config: EnvConfig) -> list[str]:
    """The lines under the table: pooled risks and whether learned ≤ rule holds everywhere."""
    from rfsas_hw.envs import protocol

    dists = [r.distance_m for r in rows]
    overall = protocol.pooled_ratio(rows, dists)  # Σ rule / Σ learned
    reduction = "—" if math.isnan(overall) or overall == 0 else f"{1 - 1 / overall:+.0%}"
    lines = [f"risk reduction over all distances, 1 − Σ learned / Σ rule: {reduction}"]
    stop = [d for d in dists if protocol.cannot_stop(config, d)]
    if stop:
        ratio = protocol.pooled_ratio(rows, stop)
        where = ", ".join(f"{d:g}" for d in stop)
        lines.append(
            f"rule/learned pooled risk where the rule cannot stop ({where} m): {ratio:.2f}"
        )
    failing = protocol.not_holding(rows)
    span = f"{min(dists):g}–{max(dists):g} m" if len(dists) > 1 else f"{dists[0]:g} m"
    if failing:
        where = ", ".join(f"{d:g}" for d in failing)
        lines.append(
            f"learned ≤ rule within one SE at every distance ({span}): NO (not at {where} m)"
        )
    else:
        lines.append(f"learned ≤ rule within one SE at every distance ({span}): yes")
    return lines


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
    help="Reward whose mean episode return is reported [default: the preset's]; "
    "risk and collisions do not depend on it.",
)
@_preset_option
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
    preset: str,
    seeds: str | None,
    prior: str | None,
    scenario: str | None,
    config_path: Path | None,
    detail: str | None,
) -> None:
    """Compare the learned policy with the rule (brake above the risk threshold, else hold)
    over the same episodes: risks with standard errors, the paired test, and whether the
    learned policy is at or below the rule at every distance."""
    from rfsas_hw.envs import protocol, rl

    for target in (csv_path, plot_path):
        if target is not None:  # a result of an earlier run may be replaced, an input never
            check_output(target, [p for p in (model_path, config_path) if p], force=True)
    config = _env_config(config_path, detail, reward, prior, scenario, preset)
    dists = rl.parse_distances(distances)
    seed_list = _parse_seeds(seeds)
    if seed_list is not None:
        if csv_path is not None or plot_path is not None:
            raise click.UsageError("--csv and --plot are for one model, not with --seeds")
        _evaluate_seeds(model_path, seed_list, dists, episodes, seed, threshold, config)
        return
    learned = rl.LearnedPolicy.load(model_path)
    _check_shape(learned, config, "the model")
    rule = rl.RulePolicy(config.risk_threshold if threshold is None else threshold)
    runs = {}
    policies: tuple[rl.Policy, ...] = (learned, rule)
    with _episode_bar() as bar:
        task = bar.add_task("episodes", total=2 * len(dists) * episodes)
        for i, policy in enumerate(policies):

            def progress(done: int, _: int, before: int = i * len(dists) * episodes) -> None:
                bar.update(task, completed=before + done)

            runs[policy.name] = protocol.outcomes(
                policy, dists, episodes, config=config, seed=seed, progress=progress
            )
    rows = protocol.compare([runs["learned"]], runs["rule"])
    title = f"learned vs rule-based braking, the same {episodes} episodes per distance"
    console = _console()
    console.print(_paired_table(rows, config.vehicle.start_distance_m, title, config.reward.kind))
    for line in _verdict(rows, config):
        console.print(line)
    if csv_path is not None or plot_path is not None:
        summary = protocol.eval_rows(runs["learned"], "learned")
        summary += protocol.eval_rows(runs["rule"], "rule")
        summary.sort(key=lambda r: dists.index(r.distance_m))
        if csv_path is not None:
            rl.write_csv(summary, csv_path)
            click.echo(f"wrote {csv_path}")
        if plot_path is not None:
            rl.plot(summary, plot_path)
            click.echo(f"wrote {plot_path}")


def _check_shape(policy: Any, config: EnvConfig, what: str) -> None:
    """Refuse a model whose observation size differs from the environment's.

    Raises:
        ConfigError: the sizes differ (a model trained with the other --prior).
    """
    from rfsas_hw.envs.env import observation_size
    from rfsas_hw.errors import ConfigError

    shape = policy.model.observation_space.shape
    expected = (observation_size(config),)
    if shape != expected:
        raise ConfigError(
            f"{what} observes {shape}, the environment gives {expected}: "
            f"pass the --prior (or --preset) it was trained with"
        )


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
            _check_shape(policy, config, f"model of seed {s}")
            task = bar.add_task(f"seed {s}", total=len(dists))
            runs = []
            for d in dists:
                runs.append(protocol.outcomes(policy, [d], episodes, seed=first, env=env))
                bar.update(task, advance=1)
            learned.append(_join(runs))
        base = protocol.outcomes(rule, dists, episodes, seed=first, env=env)
    env.close()
    rows = protocol.compare(learned, base)
    title = f"learned ({len(seeds)} seeds) vs rule, same {episodes} episodes"
    console = _console()
    console.print(_paired_table(rows, config.vehicle.start_distance_m, title, config.reward.kind))
    for line in _verdict(rows, config):
        console.print(line)


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
@_preset_option
@_prior_option
@_scenario_option
@_config_option
@_detail_option
def render(
    model_path: Path | None,
    distance: float | None,
    output: Path,
    seed: int,
    preset: str,
    prior: str | None,
    scenario: str | None,
    config_path: Path | None,
    detail: str | None,
) -> None:
    """Render one episode of the learned (or rule) policy to a video."""
    from rfsas_hw.envs import rl

    check_output(output, [p for p in (model_path, config_path) if p], force=True)
    config = _env_config(config_path, detail, prior=prior, scenario=scenario, preset=preset)
    policy: Any = (
        rl.LearnedPolicy.load(model_path)
        if model_path is not None
        else rl.RulePolicy(config.risk_threshold)
    )
    if model_path is not None:
        _check_shape(policy, config, "the model")
    info = rl.record_episode(policy, output, distance_m=distance, config=config, seed=seed)
    if info["collision"]:
        outcome = f"collision at {info['impact_speed_mps'] * 3.6:.0f} km/h"
    elif info["speed_mps"] == 0:
        outcome = f"stopped {info['distance_m']:.1f} m before the centre"
    else:
        outcome = f"no collision, crossed at {info['speed_mps'] * 3.6:.0f} km/h"
    click.echo(f"wrote {output}: {policy.name} policy, {info['t_s']:.1f} s, {outcome}")
