"""Training a PPO agent to brake, and comparing it with the rule (method.md §10).

- :func:`train`: Stable-Baselines3 PPO (``MlpPolicy``, seed 0, batch_size 64,
  ent_coef 0.0, learning_rate 3e-4, n_epochs 10, n_steps 64 by default) on
  :class:`~rfsas_hw.envs.env.IntersectionEnv`; training statistics go to CSV
  files (``progress.csv`` from the SB3 logger, ``monitor.csv`` per episode),
  never TensorBoard.
- :func:`evaluate`: the learned policy and the rule-based one (brake when the
  estimated risk is above the threshold, else hold speed) over the same
  episodes (common random numbers: the same seeds for both) at each reaction
  distance; per distance the probability of collision, the fatality risk
  given a collision and the risk ``P_collision · P_fatality``.
- :func:`risk_reduction`: ``1 − R_learned / R_rule``, per distance and pooled.
- :func:`record_episode`: one episode as a GIF (Pillow) or MP4 (ffmpeg).

stable-baselines3 (the ``rl`` extra) is imported only by the functions that
need it.
"""

from __future__ import annotations

import csv
import math
import shutil
import subprocess
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from rfsas_hw.envs.env import ACCELERATE, BRAKE, COAST, IntersectionEnv, ObsArray
from rfsas_hw.envs.envconfig import EnvConfig
from rfsas_hw.errors import ConfigError, DataFormatError, SimulationError
from rfsas_hw.optional import pyplot, require
from rfsas_hw.outpaths import save_figure

PPO_DEFAULTS: dict[str, Any] = {
    "batch_size": 64,
    "ent_coef": 0.0,
    "learning_rate": 3e-4,
    "n_epochs": 10,
    "n_steps": 64,
}
"""PPO hyper-parameters of method.md §10 (seed 0 is :func:`train`'s default)."""

CSV_COLUMNS = ("distance_m", "policy", "p_collision", "p_fatality", "risk")
"""Columns of :func:`write_csv`."""

Progress = Callable[[int, int], None]
"""Called with (steps done, steps in total) during training."""


class Policy(Protocol):
    """Chooses an action from an observation."""

    name: str

    def act(self, obs: ObsArray) -> int:
        """The action for observation ``obs``."""
        ...


@dataclass
class RulePolicy:
    """Brake while the estimated risk (observation entry 2) is above the threshold, else coast.

    With ``resume`` it accelerates instead of coasting: below the speed limit
    it drives back up to it, and at the limit accelerating holds the speed as
    coasting does. The rule as the method states it (and as it is evaluated)
    coasts, and a car that coasts at a standstill stays there; the warm start
    (:mod:`rfsas_hw.envs.warmstart`) clones the resuming rule, so that the
    policy PPO starts from drives on after a stop.
    """

    threshold: float
    name: str = "rule"
    resume: bool = False

    def act(self, obs: ObsArray) -> int:
        """BRAKE, else COAST (or ACCELERATE with ``resume``)."""
        if float(obs[2]) > self.threshold:
            return BRAKE
        return ACCELERATE if self.resume else COAST


@dataclass
class HoldPolicy:
    """Never brake: hold the initial speed (the car without RF-SAS warnings)."""

    name: str = "hold"

    def act(self, obs: ObsArray) -> int:
        """Always COAST."""
        return COAST


@dataclass
class RandomPolicy:
    """Uniformly random actions (a yardstick for learning), seeded."""

    seed: int = 0
    name: str = "random"

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng(self.seed)

    def act(self, obs: ObsArray) -> int:
        """0, 1 or 2 with equal probability."""
        return int(self._rng.integers(0, 3))


class LearnedPolicy:
    """A trained SB3 model, acting deterministically.

    Raises:
        MissingDependencyError: stable-baselines3 is not installed.
        DataFormatError: the file is not a loadable PPO model.
    """

    name = "learned"

    def __init__(self, model: Any) -> None:
        self.model = model

    @classmethod
    def load(cls, path: str | Path) -> LearnedPolicy:
        """Load a model saved by :func:`train`."""
        require("stable_baselines3")
        from stable_baselines3 import PPO

        p = Path(path)
        if not p.is_file():
            raise DataFormatError(f"{p}: no such model file")
        try:
            model = PPO.load(str(p), device="cpu")
        except Exception as err:  # SB3 raises many kinds for a foreign or damaged zip
            raise DataFormatError(f"{p}: not a PPO model saved by rfsas sim train: {err}") from err
        return cls(model)

    def act(self, obs: ObsArray) -> int:
        """The model's most likely action."""
        action, _ = self.model.predict(obs, deterministic=True)
        return int(action)


@dataclass(frozen=True)
class TrainResult:
    """What :func:`train` did."""

    model_path: Path
    """The saved model (zip)."""
    steps: int
    """Environment steps trained (fewer than asked when ``max_seconds`` stopped it)."""
    seconds: float
    """Wall time of training, seconds."""
    episodes: int
    """Episodes completed during training."""
    log_dir: Path | None
    """Directory of progress.csv and monitor.csv (None: no logs)."""
    warm_start_steps: int = 0
    """Of ``steps``, the environment steps of the rule's demonstrations (0: no warm start)."""
    warm_start_episodes: int = 0
    """Episodes of the rule's demonstrations."""
    agreement: float = float("nan")
    """After the warm start, the fraction of the demonstrated states where the policy's
    most likely action is the rule's (NaN: no warm start)."""


def _progress_callback(
    progress: Progress | None, total: int, max_seconds: float | None, done_before: int = 0
) -> Any:
    from stable_baselines3.common.callbacks import BaseCallback

    class _Progress(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.episodes = 0
            self.deadline = (
                time.perf_counter() + max_seconds if max_seconds is not None else math.inf
            )

        def _on_step(self) -> bool:
            dones = self.locals.get("dones")
            if dones is not None:
                self.episodes += int(np.sum(dones))
            if progress is not None:
                progress(min(done_before + self.num_timesteps, total), total)
            return time.perf_counter() < self.deadline

    return _Progress()


def train(
    steps: int,
    model_path: str | Path,
    *,
    config: EnvConfig | None = None,
    seed: int = 0,
    log_dir: str | Path | None = None,
    progress: Progress | None = None,
    max_seconds: float | None = None,
    n_envs: int = 1,
    warm_start_episodes: int = 0,
    **ppo: Any,
) -> TrainResult:
    """Train PPO on the environment for ``steps`` steps and save the model.

    ``ppo`` overrides entries of :data:`PPO_DEFAULTS` (or adds other PPO
    arguments). Training runs on the CPU with one torch thread. With
    ``max_seconds`` training stops early once that much wall time has passed
    (the result says how many steps were done). With ``n_envs`` > 1 the
    environments run side by side in one process (a ``DummyVecEnv``: on a
    shared 2-core machine processes would only compete); each writes its own
    ``env-<i>.monitor.csv``, and ``n_steps`` is per environment.

    With ``warm_start_episodes`` > 0 the policy starts from the rule
    (:class:`RulePolicy` at the configuration's threshold, resuming after a
    stop): that many episodes of the rule (fewer when they would take more
    than a quarter of ``steps``), a fifth of their actions random, are cloned
    into the actor and the critic (:mod:`rfsas_hw.envs.warmstart`) before PPO
    runs. Their environment steps count in ``steps``: PPO gets the rest (at
    least one rollout).

    Raises:
        MissingDependencyError: stable-baselines3 is not installed.
        ConfigError: ``steps`` < 1, ``n_envs`` < 1 or ``warm_start_episodes`` < 0.
    """
    if warm_start_episodes < 0:
        raise ConfigError(f"warm_start_episodes must be >= 0, got {warm_start_episodes}")
    if steps < 1:
        raise ConfigError(f"training needs at least one step, got {steps}")
    if n_envs < 1:
        raise ConfigError(f"training needs at least one environment, got n_envs={n_envs}")
    require("stable_baselines3")
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.monitor import Monitor

    torch.set_num_threads(1)
    out = Path(model_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    logs = Path(log_dir) if log_dir is not None else None
    if logs is not None:
        logs.mkdir(parents=True, exist_ok=True)
    from stable_baselines3.common.vec_env import DummyVecEnv

    keys = ("collision", "impact_speed_mps", "reaction_distance_m")

    def monitored(i: int) -> Callable[[], Any]:
        name = "monitor.csv" if n_envs == 1 else f"env-{i}.monitor.csv"
        filename = str(logs / name) if logs is not None else None
        return lambda: Monitor(IntersectionEnv(config), filename=filename, info_keywords=keys)

    env: Any = monitored(0)() if n_envs == 1 else DummyVecEnv([monitored(i) for i in range(n_envs)])
    params = {**PPO_DEFAULTS, **ppo}
    model = PPO("MlpPolicy", env, seed=seed, device="cpu", verbose=0, **params)
    if logs is not None:
        model.set_logger(configure(str(logs), ["csv"]))
    start = time.perf_counter()
    demo_steps, demo_episodes, agreement = 0, 0, math.nan
    try:
        if warm_start_episodes > 0:
            demo_steps, demo_episodes, agreement = _warm_start(
                model, config, seed, warm_start_episodes, steps
            )
            if progress is not None:
                progress(min(demo_steps, steps), steps)
        callback = _progress_callback(progress, steps, max_seconds, demo_steps)
        model.learn(total_timesteps=max(steps - demo_steps, 1), callback=callback)
    finally:
        model.logger.close()
        env.close()
    seconds = time.perf_counter() - start
    model.save(str(out))
    saved = out if out.suffix == ".zip" else out.with_name(out.name + ".zip")
    done = int(model.num_timesteps) + demo_steps
    return TrainResult(
        saved, done, seconds, callback.episodes, logs, demo_steps, demo_episodes, agreement
    )


def _warm_start(
    model: Any, config: EnvConfig | None, seed: int, episodes: int, budget: int
) -> tuple[int, int, float]:
    """Clone the resuming rule into ``model``'s policy; the demonstrations' steps and
    episodes, and the agreement after cloning."""
    from rfsas_hw.envs.warmstart import clone, demonstrations

    teacher = RulePolicy((config or EnvConfig()).risk_threshold, resume=True)
    demo = demonstrations(
        teacher, episodes, config=config, seed=seed, gamma=model.gamma, max_steps=budget // 4
    )
    stats = clone(model.policy, demo, seed=seed)
    return demo.steps, demo.episodes, stats.agreement


@dataclass(frozen=True)
class EvalRow:
    """One policy at one reaction distance."""

    distance_m: float
    """Reaction distance: where a car holding its speed gets the warning, metres."""
    policy: str
    """``learned``, ``rule`` (or another policy's name)."""
    episodes: int
    """Episodes run."""
    collisions: int
    """Episodes that ended in a collision."""
    p_collision: float
    """Fraction of episodes with a collision."""
    p_fatality: float
    """Mean fatality risk ``P_f(impact speed)`` over the collisions (NaN without any)."""
    risk: float
    """Mean realised risk per episode: ``p_collision · p_fatality`` (0 without collisions)."""
    risk_stderr: float
    """Standard error of ``risk`` over the episodes."""
    mean_time_s: float
    """Mean episode duration, seconds (how much the policy slows the car down)."""
    mean_return: float = math.nan
    """Mean undiscounted episode return under the environment's reward."""
    timeouts: float = 0.0
    """Fraction of episodes that ended at ``max_steps`` with the car short of the crossing
    (no collision, but not safe either: the car never arrived)."""


def run_episode(
    env: IntersectionEnv,
    policy: Policy,
    seed: int,
    distance_m: float | None = None,
    options: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Run one episode; return the final ``info`` with the number of steps, whether it
    was truncated and its undiscounted ``return`` (sum of the rewards).

    ``options`` are further ``reset`` options (``corner``, ``crosser``, ``heard``).
    """
    opts = dict(options or {})
    if distance_m is not None:
        opts["reaction_distance_m"] = distance_m
    obs, info = env.reset(seed=seed, options=opts or None)
    steps = 0
    total = 0.0
    while True:
        obs, reward, term, trunc, info = env.step(policy.act(obs))
        steps += 1
        total += float(reward)
        if term or trunc:
            break
    return {**info, "steps": steps, "truncated": bool(trunc), "return": total}


def evaluate(
    policies: Sequence[Policy],
    distances_m: Iterable[float],
    episodes: int,
    *,
    config: EnvConfig | None = None,
    seed: int = 10_000,
    progress: Callable[[int, int], None] | None = None,
) -> list[EvalRow]:
    """Run every policy for ``episodes`` episodes at each reaction distance.

    Episode ``k`` uses seed ``seed + k`` for every policy and distance, so the
    policies meet the same cross traffic and measurement noise
    (:func:`rfsas_hw.envs.protocol.outcomes` runs them). ``progress`` is called
    after each episode with (episodes done, episodes in all). Rows come by
    distance, the policies in the order given.

    Raises:
        ConfigError: ``episodes`` < 1.
    """
    # the protocol runs the episodes; it builds on this module, hence the late import
    from rfsas_hw.envs.protocol import eval_rows, outcomes

    if episodes < 1:
        raise ConfigError(f"evaluation needs at least one episode, got {episodes}")
    distances = [float(d) for d in distances_m]
    per_policy = len(distances) * episodes
    total = len(policies) * per_policy
    rows: list[EvalRow] = []
    env = IntersectionEnv(config)
    try:
        for j, policy in enumerate(policies):

            def report(done: int, _: int, before: int = j * per_policy) -> None:
                if progress is not None:
                    progress(before + done, total)

            o = outcomes(policy, distances, episodes, seed=seed, env=env, progress=report)
            rows += eval_rows(o, policy.name)
    finally:
        env.close()
    # by distance, the policies in the order given within each
    rows.sort(key=lambda r: distances.index(r.distance_m))
    return rows


def risk_reduction(
    rows: Sequence[EvalRow], learned: str = "learned", baseline: str = "rule"
) -> tuple[dict[float, float], float]:
    """Relative risk reduction ``1 − R_learned / R_baseline``: per distance, and pooled.

    The pooled value divides the summed risks (equal episode counts per
    distance), not the mean of the per-distance ratios. A distance where the
    baseline's risk is 0 gives NaN (a reduction relative to nothing).
    """
    by = {(r.distance_m, r.policy): r for r in rows}
    per: dict[float, float] = {}
    num = den = 0.0
    for (d, name), r in sorted(by.items()):
        if name != learned or (d, baseline) not in by:
            continue
        base = by[(d, baseline)]
        per[d] = 1.0 - r.risk / base.risk if base.risk > 0 else math.nan
        num += r.risk * r.episodes
        den += base.risk * base.episodes
    pooled = 1.0 - num / den if den > 0 else math.nan
    return per, pooled


def parse_distances(text: str) -> list[float]:
    """``start:stop:step`` (stop included) or a comma list of distances, metres.

    Raises:
        ConfigError: not numbers, a non-positive step, or a negative distance.
    """
    try:
        if ":" in text:
            parts = [float(p) for p in text.split(":")]
            if len(parts) != 3:
                raise ValueError("need start:stop:step")
            start, stop, step = parts
            if step <= 0:
                raise ValueError("step must be positive")
            values = list(np.arange(start, stop + step / 2, step))
        else:
            values = [float(p) for p in text.split(",") if p.strip()]
    except ValueError as err:
        raise ConfigError(f"distances {text!r}: {err}") from err
    if not values or any(v < 0 for v in values):
        raise ConfigError(f"distances {text!r}: need one or more distances ≥ 0 m")
    return [float(v) for v in values]


def write_csv(rows: Sequence[EvalRow], path: str | Path) -> None:
    """Write ``distance_m,policy,p_collision,p_fatality,risk`` rows (NaN written as ``nan``)."""
    with Path(path).open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(CSV_COLUMNS)
        for r in rows:
            p_f = f"{r.p_fatality:.6g}"
            w.writerow(
                [f"{r.distance_m:g}", r.policy, f"{r.p_collision:.6g}", p_f, f"{r.risk:.6g}"]
            )


def plot(rows: Sequence[EvalRow], path: str | Path) -> None:
    """Draw collision probability, fatality risk and risk against reaction distance (PNG).

    Raises:
        MissingDependencyError: matplotlib is not installed.
    """
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6), constrained_layout=True)
    names = list(dict.fromkeys(r.policy for r in rows))
    for name in names:
        mine = sorted((r for r in rows if r.policy == name), key=lambda r: r.distance_m)
        d = [r.distance_m for r in mine]
        axes[0].plot(d, [r.p_collision for r in mine], "o-", label=name)
        axes[1].plot(d, [r.p_fatality for r in mine], "o-", label=name)
        axes[2].errorbar(
            d, [r.risk for r in mine], yerr=[r.risk_stderr for r in mine], fmt="o-", label=name
        )
    for ax, title in zip(
        axes, ("P(collision)", "fatality risk given a collision", "risk"), strict=True
    ):
        ax.set_xlabel("reaction distance (m)")
        ax.set_title(title)
        ax.grid(alpha=0.3)
    axes[0].legend()
    try:
        save_figure(fig, path, dpi=110)
    finally:
        plt.close(fig)


def record_episode(
    policy: Policy,
    path: str | Path,
    *,
    distance_m: float | None = None,
    config: EnvConfig | None = None,
    seed: int = 0,
) -> dict[str, Any]:
    """Render one episode to ``path``: ``.gif`` (Pillow) or ``.mp4`` (needs ffmpeg).

    Returns the episode's final info.

    Raises:
        ConfigError: another extension, or ``.mp4`` without ffmpeg on the PATH.
        MissingDependencyError: pygame (or Pillow for GIF) is not installed.
    """
    out = Path(path)
    ext = out.suffix.lower()
    if ext not in (".gif", ".mp4"):
        raise ConfigError(f"{out}: video must be .gif or .mp4")
    ffmpeg = shutil.which("ffmpeg")
    if ext == ".mp4" and ffmpeg is None:
        raise ConfigError(f"{out}: writing MP4 needs ffmpeg on the PATH; use a .gif name instead")
    env = IntersectionEnv(config, render_mode="rgb_array")
    options = None if distance_m is None else {"reaction_distance_m": distance_m}
    obs, info = env.reset(seed=seed, options=options)
    frames: list[npt.NDArray[np.uint8]] = [_frame(env)]
    while True:
        obs, _, term, trunc, info = env.step(policy.act(obs))
        frames.append(_frame(env))
        if term or trunc:
            break
    fps = int(env.metadata["render_fps"])
    env.close()
    # hold the last frame for a second so the outcome can be read
    frames.extend([frames[-1]] * fps)
    if ext == ".gif":
        _write_gif(frames, out, fps)
    else:
        assert ffmpeg is not None
        _write_mp4(frames, out, fps, ffmpeg)
    return info


def _frame(env: IntersectionEnv) -> npt.NDArray[np.uint8]:
    frame = env.render()
    if frame is None:
        raise SimulationError("the environment returned no frame")
    return frame


def _write_gif(frames: list[npt.NDArray[np.uint8]], path: Path, fps: int) -> None:
    image = require("PIL.Image")
    # the fast octree quantiser keeps the few flat colours of the map exact
    fast = image.Quantize.FASTOCTREE
    pics = [image.fromarray(f).quantize(colors=64, method=fast) for f in frames]
    pics[0].save(
        str(path), save_all=True, append_images=pics[1:], duration=round(1000 / fps), loop=0
    )


def _write_mp4(frames: list[npt.NDArray[np.uint8]], path: Path, fps: int, ffmpeg: str) -> None:
    h, w, _ = frames[0].shape
    cmd = [
        ffmpeg, "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24",
        "-s", f"{w}x{h}", "-r", str(fps), "-i", "-",
        "-pix_fmt", "yuv420p", "-vcodec", "libx264", str(path),
    ]  # fmt: skip
    try:
        subprocess.run(cmd, input=b"".join(f.tobytes() for f in frames), check=True)
    except (OSError, subprocess.CalledProcessError) as err:
        raise SimulationError(f"{path}: ffmpeg failed: {err}") from err


__all__ = [
    "ACCELERATE",
    "CSV_COLUMNS",
    "PPO_DEFAULTS",
    "EvalRow",
    "HoldPolicy",
    "LearnedPolicy",
    "Policy",
    "RandomPolicy",
    "RulePolicy",
    "TrainResult",
    "evaluate",
    "parse_distances",
    "plot",
    "record_episode",
    "risk_reduction",
    "run_episode",
    "train",
    "write_csv",
]
