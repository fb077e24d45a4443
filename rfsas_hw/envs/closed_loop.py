"""Closed-loop comparisons on wrapped driving envs: collisions with and without RF-SAS.

:func:`run_episode` drives one seeded episode of an
:class:`~rfsas_hw.envs.rfsas_wrapper.RfsasWrapper` with a policy and
reports whether and how fast the ego hit something. :func:`compare` runs the
same seeds under several conditions (e.g. the plain policy and the same
policy behind the shield: common random numbers, so the crossers, the
traffic and the radio are the same in both), and :func:`summarise` gives the
collision rate with its standard error over seeds.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rfsas_hw.envs.rfsas_wrapper import RfsasWrapper

Policy = Callable[[Any, RfsasWrapper], Any]
"""Chooses an action from an observation (and the env, for its action conventions)."""

__all__ = ["EpisodeOutcome", "Summary", "compare", "run_episode", "summarise"]


@dataclass(frozen=True)
class EpisodeOutcome:
    """What happened in one episode."""

    seed: int
    """Episode seed."""
    collided: bool
    """Whether the ego hit anything."""
    impact_speed_mps: float
    """Ego speed at the last step before the collision, m/s (0 without one)."""
    steps: int
    """Steps driven."""
    first_brake_s: float | None
    """Episode time of the first BRAKE advisory, seconds (None: none came)."""
    shielded_steps: int
    """Steps in which the shield replaced the action."""


@dataclass(frozen=True)
class Summary:
    """Collision statistics of one condition over seeds."""

    condition: str
    """Name of the condition."""
    episodes: int
    """Episodes (seeds)."""
    collisions: int
    """Episodes with a collision."""
    rate: float
    """Mean collision indicator over seeds."""
    stderr: float
    """Standard error of ``rate`` (sample standard deviation / √n; 0 for one episode)."""
    mean_impact_mps: float
    """Mean impact speed over the episodes with a collision, m/s (NaN: none)."""


def run_episode(env: RfsasWrapper, policy: Policy, seed: int, max_steps: int) -> EpisodeOutcome:
    """Drive one episode of ``env`` seeded by ``seed`` for at most ``max_steps`` steps."""
    obs, info = env.reset(seed=seed)
    first_brake: float | None = None
    shielded = 0
    speed = env.snapshot.ego.speed_mps if env.snapshot is not None else 0.0
    for k in range(1, max_steps + 1):
        obs, _, terminated, truncated, info = env.step(policy(obs, env))
        rf = info["rfsas"]
        shielded += int(rf["shielded"])
        if rf["advisory"] == "brake" and first_brake is None and env.snapshot is not None:
            first_brake = env.snapshot.t_s
        if rf["collision"]:
            return EpisodeOutcome(seed, True, speed, k, first_brake, shielded)
        if env.snapshot is not None:
            speed = env.snapshot.ego.speed_mps
        if terminated or truncated:
            return EpisodeOutcome(seed, False, 0.0, k, first_brake, shielded)
    return EpisodeOutcome(seed, False, 0.0, max_steps, first_brake, shielded)


def compare(
    conditions: Mapping[str, Callable[[], RfsasWrapper]],
    policy: Policy,
    seeds: Iterable[int],
    max_steps: int,
) -> dict[str, list[EpisodeOutcome]]:
    """Every condition's outcomes over the same ``seeds`` (envs built by the factories)."""
    seeds = list(seeds)
    out: dict[str, list[EpisodeOutcome]] = {}
    for name, make in conditions.items():
        env = make()
        try:
            out[name] = [run_episode(env, policy, s, max_steps) for s in seeds]
        finally:
            env.close()
    return out


def summarise(condition: str, outcomes: Sequence[EpisodeOutcome]) -> Summary:
    """Collision rate and its standard error over ``outcomes``."""
    hits = np.array([o.collided for o in outcomes], np.float64)
    n = len(hits)
    rate = float(hits.mean()) if n else math.nan
    stderr = float(hits.std(ddof=1) / math.sqrt(n)) if n > 1 else 0.0
    speeds = [o.impact_speed_mps for o in outcomes if o.collided]
    return Summary(
        condition,
        n,
        int(hits.sum()),
        rate,
        stderr,
        float(np.mean(speeds)) if speeds else math.nan,
    )
