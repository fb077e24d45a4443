"""The learned-vs-rule protocol: several seeds, paired episodes, standard errors, tests.

- :func:`train_seeds`: one PPO run per seed (vectorised environments) on the
  project's runner (seeds side by side on Dask workers, or one after the
  other here), each saved as ``<stem>-seed-<s>.zip`` with its logs in
  ``<stem>-seed-<s>-logs``.
- :func:`outcomes`: one policy over the same episodes at each reaction
  distance (episode ``k`` has seed ``seed + k`` for every policy): the
  realised risk, collision and duration of every episode.
- :func:`compare`: the seeds of the learned policy against a baseline, per
  distance: mean risk, its standard error over the seeds and over the
  episodes, the baseline's, and a paired t-test over the episodes of the
  seed-averaged learned risk against the baseline's (the same episodes).
- :func:`pooled_ratio`: the baseline's summed risk over the learned one's
  over chosen distances (e.g. where the rule cannot stop in time).
- :func:`not_holding`: the distances where the learned policy is *not* at
  or below the baseline within one standard error, or times out more often
  (a car that parks short of the crossing has no collision, but it is not
  safe: it never arrives).
- :func:`eval_rows`: one policy's outcomes as per-distance
  :class:`~rfsas_hw.envs.rl.EvalRow` summaries (CSV, plot).
- :func:`speed_profiles` and :func:`plot_speed_profiles`: the mean speed
  along the approach, with and without a warning.

Reaction distances are measured from the intersection centre; the method
(method.md §10) measures them from the start line, ``start_distance_m − d``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.envs.env import IntersectionEnv
from rfsas_hw.envs.envconfig import EnvConfig
from rfsas_hw.envs.rl import EvalRow, Policy, Progress, TrainResult, train
from rfsas_hw.errors import ConfigError
from rfsas_hw.optional import pyplot
from rfsas_hw.outpaths import save_figure
from rfsas_hw.parallel import run_tasks

__all__ = [
    "Outcomes",
    "PairedRow",
    "TrainJob",
    "cannot_stop",
    "compare",
    "eval_rows",
    "not_holding",
    "outcomes",
    "plot_speed_profiles",
    "pooled_ratio",
    "seed_model_path",
    "speed_profiles",
    "train_job",
    "train_seeds",
]

Array = npt.NDArray[np.float64]


def seed_model_path(model_path: str | Path, seed: int) -> Path:
    """Where the model of ``seed`` goes for ``model_path``: ``<stem>-seed-<s>.zip``."""
    p = Path(model_path)
    stem = p.stem if p.suffix == ".zip" else p.name
    return p.with_name(f"{stem}-seed-{seed}.zip")


@dataclass(frozen=True)
class TrainJob:
    """One seed's training as handed to the runner (picklable: it may run in a worker
    process)."""

    seed: int
    steps: int
    model_path: Path
    """Where this seed's model goes (see :func:`seed_model_path`)."""
    config: EnvConfig | None
    n_envs: int
    max_seconds: float | None
    ppo: Mapping[str, Any]


def train_job(job: TrainJob, progress: Progress | None = None) -> TrainResult:
    """:func:`~rfsas_hw.envs.rl.train` of ``job``, its logs in ``<model stem>-logs``.

    Raises:
        as :func:`~rfsas_hw.envs.rl.train`.
    """
    return train(
        job.steps,
        job.model_path,
        config=job.config,
        seed=job.seed,
        log_dir=job.model_path.with_name(job.model_path.stem + "-logs"),
        progress=progress,
        max_seconds=job.max_seconds,
        n_envs=job.n_envs,
        **job.ppo,
    )


def train_seeds(
    seeds: Sequence[int],
    steps: int,
    model_path: str | Path,
    *,
    config: EnvConfig | None = None,
    n_envs: int = 4,
    progress: Callable[[int], Progress | None] | None = None,
    max_seconds: float | None = None,
    workers: int = 0,
    scheduler: str | None = None,
    on_seed: Callable[[int, TrainResult], None] | None = None,
    **ppo: Any,
) -> list[TrainResult]:
    """Train one PPO model per seed on the project's runner (:mod:`rfsas_hw.parallel`:
    ``workers`` processes of a local Dask cluster, a ``scheduler``, or this process with
    ``workers=0``); the results in the order of ``seeds``.

    Seed ``s`` is saved as :func:`seed_model_path` (``<stem>-seed-<s>.zip``) with its
    logs in ``<stem>-seed-<s>-logs``. Each seed's training is seeded and independent, so
    the models do not depend on ``workers`` (unless ``max_seconds`` cuts them short).

    Args:
        progress: ``progress(seed)`` gives that seed's per-step progress callback; only
            when training here (``workers=0`` and no scheduler).
        on_seed: called with each seed and its result as it finishes.

    Raises:
        ConfigError: no seeds, repeated seeds, or ``steps`` < 1.
        MissingDependencyError: stable-baselines3 (or, with workers, Dask distributed) is
            not installed.
    """
    if not seeds or len(set(seeds)) != len(seeds):
        raise ConfigError(f"seeds must be one or more distinct integers, got {list(seeds)}")
    if steps < 1:
        raise ConfigError(f"training needs at least one step, got {steps}")
    jobs = [
        TrainJob(s, steps, seed_model_path(model_path, s), config, n_envs, max_seconds, ppo)
        for s in seeds
    ]
    fn: Callable[[TrainJob], TrainResult] = train_job
    if workers == 0 and scheduler is None and progress is not None:
        per_seed = progress

        def fn(job: TrainJob) -> TrainResult:
            return train_job(job, per_seed(job.seed))

    def done(i: int, result: TrainResult) -> None:
        if on_seed is not None:
            on_seed(jobs[i].seed, result)

    return run_tasks(fn, jobs, workers=workers, scheduler=scheduler, name="train", on_result=done)


@dataclass(frozen=True)
class Outcomes:
    """Every episode of one policy: arrays of shape (distances, episodes)."""

    distances_m: tuple[float, ...]
    """Reaction distances from the centre, metres."""
    risk: Array
    """Realised fatality risk of each episode (0 without a collision)."""
    collision: npt.NDArray[np.bool_]
    """Whether each episode ended in a collision."""
    time_s: Array
    """Duration of each episode, seconds."""
    crossed: npt.NDArray[np.bool_]
    """Whether the car crossed (False: a collision or a timeout)."""
    returns: Array | None = None
    """Undiscounted return of each episode under the environment's reward (None: not kept)."""

    @property
    def timeouts(self) -> npt.NDArray[np.bool_]:
        """Episodes that ended at ``max_steps`` without a crossing or a collision."""
        return ~self.crossed & ~self.collision


def outcomes(
    policy: Policy,
    distances_m: Sequence[float | None],
    episodes: int,
    *,
    config: EnvConfig | None = None,
    seed: int = 10_000,
    options: Mapping[str, Any] | None = None,
    env: IntersectionEnv | None = None,
    progress: Progress | None = None,
) -> Outcomes:
    """Run ``policy`` for ``episodes`` episodes at each reaction distance.

    A distance of None lets ``reset`` place the warning as in training.
    ``progress`` is called after each episode with (episodes done, episodes in all).

    Raises:
        ConfigError: ``episodes`` < 1.
    """
    from rfsas_hw.envs.rl import run_episode

    if episodes < 1:
        raise ConfigError(f"evaluation needs at least one episode, got {episodes}")
    own = env is None
    env = IntersectionEnv(config) if env is None else env
    shape = (len(distances_m), episodes)
    risk, hit, times = np.zeros(shape), np.zeros(shape, bool), np.zeros(shape)
    crossed = np.zeros(shape, bool)
    returns = np.zeros(shape)
    for i, d in enumerate(distances_m):
        for k in range(episodes):
            info = run_episode(env, policy, seed + k, d, dict(options or {}))
            risk[i, k] = info["realised_risk"]
            hit[i, k] = info["collision"]
            times[i, k] = info["t_s"]
            crossed[i, k] = info["crossed"]
            returns[i, k] = info["return"]
            if progress is not None:
                progress(i * episodes + k + 1, len(distances_m) * episodes)
    if own:
        env.close()
    dists = tuple(math.nan if d is None else float(d) for d in distances_m)
    return Outcomes(dists, risk, hit, times, crossed, returns)


@dataclass(frozen=True)
class PairedRow:
    """The learned policy's seeds against the baseline at one reaction distance."""

    distance_m: float
    """Reaction distance from the centre, metres."""
    seeds: int
    """Learned models (training seeds)."""
    episodes: int
    """Episodes per policy (the same for all)."""
    risk: float
    """Mean realised risk of the learned policy over seeds and episodes."""
    risk_se_seeds: float
    """Standard error of the per-seed mean risks (NaN with one seed)."""
    risk_se_episodes: float
    """Standard error over the episodes of the seed-averaged risk."""
    p_collision: float
    """Fraction of the learned policy's episodes with a collision (all seeds)."""
    seeds_at_or_below: int
    """Seeds whose mean risk is at or below the baseline's."""
    baseline_risk: float
    """Mean realised risk of the baseline."""
    baseline_se: float
    """Its standard error over the episodes."""
    baseline_p_collision: float
    """Fraction of the baseline's episodes with a collision."""
    p_value: float
    """Two-sided paired t-test over the episodes: seed-averaged learned risk against the
    baseline's (1 where every difference is 0)."""
    time_s: float
    """Mean episode duration of the learned policy, seconds."""
    baseline_time_s: float
    """Mean episode duration of the baseline, seconds."""
    timeouts: float = 0.0
    """Fraction of the learned policy's episodes (all seeds) that timed out uncrossed."""
    mean_return: float = math.nan
    """Mean episode return of the learned policy (all seeds; NaN: returns not kept)."""
    baseline_return: float = math.nan
    """Mean episode return of the baseline."""
    difference_se: float = math.nan
    """Standard error over the episodes of the paired difference, seed-averaged learned
    risk minus the baseline's (NaN with one episode)."""
    baseline_timeouts: float = 0.0
    """Fraction of the baseline's episodes that timed out uncrossed."""

    @property
    def holds(self) -> bool:
        """Whether the learned policy is at or below the baseline here: its risk exceeds
        the baseline's by at most one standard error of the paired difference, and it
        times out no more often (a timeout has no collision, but the car never arrived)."""
        margin = 0.0 if math.isnan(self.difference_se) else self.difference_se
        return (
            self.risk <= self.baseline_risk + margin + 1e-12
            and self.timeouts <= self.baseline_timeouts + 1e-12
        )


def _se(x: Array) -> float:
    return float(np.std(x, ddof=1) / math.sqrt(len(x))) if len(x) > 1 else math.nan


def _constant(diff: Array) -> bool:
    """Whether every episode's difference is the same, to rounding (no spread to test)."""
    return float(np.ptp(diff)) <= 1e-12 * max(1.0, float(np.abs(diff).max()))


def _paired_p(diff: Array) -> float:
    """The paired test's p-value when the differences have no spread: 1 when they are
    all 0, else 0 (the same nonzero difference in every episode; a t statistic without
    spread is infinite, and scipy's moment calculation would lose its precision)."""
    return 1.0 if np.allclose(diff, 0.0) else 0.0


def compare(learned: Sequence[Outcomes], baseline: Outcomes) -> list[PairedRow]:
    """Per-distance statistics of the learned seeds against the baseline (same episodes).

    Raises:
        ConfigError: no learned outcomes, or outcomes of other distances or episodes.
    """
    from scipy.stats import ttest_rel

    if not learned:
        raise ConfigError("compare needs the outcomes of at least one learned model")
    for o in learned:
        if o.distances_m != baseline.distances_m or o.risk.shape != baseline.risk.shape:
            raise ConfigError("compare: every policy must run the same distances and episodes")
    stack = np.stack([o.risk for o in learned])  # (seeds, distances, episodes)
    hits = np.stack([o.collision for o in learned])
    times = np.stack([o.time_s for o in learned])
    timeouts = np.stack([o.timeouts for o in learned])
    kept = baseline.returns is not None and all(o.returns is not None for o in learned)
    returns = np.stack([o.returns for o in learned]) if kept else None  # type: ignore[misc]
    rows = []
    for i, d in enumerate(baseline.distances_m):
        per_seed = stack[:, i, :].mean(axis=1)
        averaged = stack[:, i, :].mean(axis=0)
        base = baseline.risk[i]
        diff = averaged - base
        p = _paired_p(diff) if _constant(diff) else float(ttest_rel(averaged, base).pvalue)
        rows.append(
            PairedRow(
                distance_m=d,
                seeds=len(learned),
                episodes=base.size,
                risk=float(averaged.mean()),
                risk_se_seeds=_se(per_seed),
                risk_se_episodes=_se(averaged),
                p_collision=float(hits[:, i, :].mean()),
                seeds_at_or_below=int(np.sum(per_seed <= base.mean() + 1e-12)),
                baseline_risk=float(base.mean()),
                baseline_se=_se(base),
                baseline_p_collision=float(baseline.collision[i].mean()),
                p_value=p,
                time_s=float(times[:, i, :].mean()),
                baseline_time_s=float(baseline.time_s[i].mean()),
                timeouts=float(timeouts[:, i, :].mean()),
                mean_return=float(returns[:, i, :].mean()) if returns is not None else math.nan,
                baseline_return=float(baseline.returns[i].mean())  # type: ignore[index]
                if returns is not None
                else math.nan,
                difference_se=_se(diff),
                baseline_timeouts=float(baseline.timeouts[i].mean()),
            )
        )
    return rows


def not_holding(rows: Sequence[PairedRow]) -> list[float]:
    """The distances (metres) where the learned policy does not hold against the baseline
    (:attr:`PairedRow.holds`); empty when it holds at every distance."""
    return [r.distance_m for r in rows if not r.holds]


def eval_rows(o: Outcomes, name: str) -> list[EvalRow]:
    """Per-distance summaries of one policy's episodes, named ``name``."""
    rows = []
    for i, d in enumerate(o.distances_m):
        risk, hit = o.risk[i], o.collision[i]
        n = risk.size
        rows.append(
            EvalRow(
                distance_m=d,
                policy=name,
                episodes=n,
                collisions=int(hit.sum()),
                p_collision=float(hit.mean()),
                p_fatality=float(risk[hit].mean()) if hit.any() else math.nan,
                risk=float(risk.mean()),
                risk_stderr=_se(risk),
                mean_time_s=float(o.time_s[i].mean()),
                mean_return=float(o.returns[i].mean()) if o.returns is not None else math.nan,
                timeouts=float(o.timeouts[i].mean()),
            )
        )
    return rows


def cannot_stop(config: EnvConfig, distance_m: float) -> bool:
    """Whether a car at its top initial speed, braking one step after a warning at
    ``distance_m`` from the centre, cannot stop before the crosser's path."""
    v = config.vehicle
    u = v.initial_speed_mps[1]
    room = distance_m - abs(config.obstacle.crossing_y_m) - 0.5
    return room < u * u / (2 * v.brake_mps2) + u * config.dt_s


def pooled_ratio(rows: Sequence[PairedRow], distances_m: Sequence[float]) -> float:
    """Baseline's summed risk over the learned policy's, over ``distances_m``
    (inf when the learned risk is 0 and the baseline's is not; NaN when both are)."""
    chosen = [r for r in rows if r.distance_m in set(distances_m)]
    num = sum(r.baseline_risk for r in chosen)
    den = sum(r.risk for r in chosen)
    if den == 0:
        return math.inf if num > 0 else math.nan
    return num / den


def speed_profiles(
    policy: Policy,
    episodes: int,
    *,
    config: EnvConfig | None = None,
    seed: int = 20_000,
    options: Mapping[str, Any] | None = None,
    grid_m: Array | None = None,
) -> tuple[Array, Array]:
    """Mean speed (m/s) of ``policy`` against the distance to the centre (``grid_m``, metres,
    default 100 → 0 m every 2 m); an episode that ended before a grid point (a collision
    or a timeout) counts with its last speed there.

    Raises:
        ConfigError: ``episodes`` < 1.
    """
    if episodes < 1:
        raise ConfigError(f"speed profiles need at least one episode, got {episodes}")
    env = IntersectionEnv(config)
    grid = np.arange(env.config.vehicle.start_distance_m, -0.5, -2.0) if grid_m is None else grid_m
    speeds = np.zeros((episodes, len(grid)))
    for k in range(episodes):
        obs, _ = env.reset(seed=seed + k, options=dict(options or {}) or None)
        dist, speed = [env.distance_m], [env.speed_mps]
        done = False
        while not done:
            obs, _, term, trunc, _ = env.step(policy.act(obs))
            dist.append(env.distance_m)
            speed.append(env.speed_mps)
            done = term or trunc
        d, v = np.array(dist[::-1]), np.array(speed[::-1])
        speeds[k] = np.interp(grid, d, v, left=v[0], right=v[-1])
    env.close()
    return grid, speeds.mean(axis=0)


def plot_speed_profiles(curves: Mapping[str, tuple[Array, Array]], path: str | Path) -> None:
    """Draw speed against distance to the centre for each curve (PNG).

    Curves are named ``"policy, panel, case"`` (e.g. ``"rule, busy, no warning"``):
    one panel per distinct second field, one colour per policy, a solid line for
    cases without a warning and a dashed one otherwise. Names with fewer fields go
    to a single panel.

    Raises:
        MissingDependencyError: matplotlib is not installed.
    """
    plt = pyplot()
    parts = {name: [*name.split(", ", 2), "", ""][:3] for name in curves}
    panels = list(dict.fromkeys(p[1] for p in parts.values()))
    policies = list(dict.fromkeys(p[0] for p in parts.values()))
    colours = {name: f"C{i % 10}" for i, name in enumerate(policies)}
    fig, axes = plt.subplots(
        1, len(panels), figsize=(5 * len(panels), 4), sharey=True, constrained_layout=True
    )
    axes = np.atleast_1d(axes)
    for name, (grid, speed) in curves.items():
        policy, panel, case = parts[name]
        ax = axes[panels.index(panel)]
        style = "-" if case in ("", "no warning") else "--"
        label = f"{policy}, {case}" if case else policy
        ax.plot(grid, speed * 3.6, style, color=colours[policy], label=label)
    for ax, panel in zip(axes, panels, strict=True):
        ax.invert_xaxis()
        ax.set_title(panel)
        ax.set_xlabel("distance of the front bumper to the centre (m)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    axes[0].set_ylabel("mean speed (km/h)")
    try:
        save_figure(fig, path, dpi=110)
    finally:
        plt.close(fig)
