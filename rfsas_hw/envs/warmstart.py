"""Starting PPO from the rule: behaviour cloning before reinforcement learning.

A PPO policy drawn at random brakes in a third of its steps, so the car of
its first rollouts crawls or stops, and with a small step budget some seeds
never learn to drive on (they park short of the crossing). Warm-starting
puts every seed at the same, sensible starting point, the rule-based policy
(:class:`~rfsas_hw.envs.rl.RulePolicy`), and leaves PPO to improve on it:

- :func:`demonstrations`: episodes of the environment driven by a *teacher*
  policy, with a share ``explore`` of the actions drawn at random, so that
  the states around the teacher's path (slower, stopped) are seen too. Every
  state is labelled with the teacher's action there, and with the discounted
  return that followed it.
- :func:`clone`: fits the PPO actor to the labels by cross-entropy against
  a smoothed target (the teacher's action with probability ``1 − smoothing``,
  the rest shared by the other actions, so that PPO still explores), and the
  critic to the returns (mean squared error), together.

The environment steps of the demonstrations are part of a training run's
budget (:func:`rfsas_hw.envs.rl.train` gives them at most a quarter of it and
PPO the rest).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.envs.env import IntersectionEnv
from rfsas_hw.envs.envconfig import EnvConfig
from rfsas_hw.errors import ConfigError

__all__ = ["CloneStats", "Demonstrations", "clone", "demonstrations"]


@dataclass(frozen=True)
class Demonstrations:
    """Labelled states from :func:`demonstrations` (one row per environment step)."""

    obs: npt.NDArray[np.float32]
    """Observations, shape (steps, observation size)."""
    actions: npt.NDArray[np.int64]
    """The teacher's action in each state (not necessarily the action taken)."""
    returns: npt.NDArray[np.float64]
    """Discounted return from each state on, under the actions taken."""
    episodes: int
    """Episodes run."""

    @property
    def steps(self) -> int:
        """Environment steps taken."""
        return len(self.actions)


@dataclass(frozen=True)
class CloneStats:
    """How well the cloned policy fits its teacher (on the demonstrations)."""

    agreement: float
    """Fraction of the states where the policy's most likely action is the teacher's."""
    value_rmse: float
    """Root mean square error of the critic against the returns."""


def demonstrations(
    teacher: Any,
    episodes: int,
    *,
    config: EnvConfig | None = None,
    seed: int = 0,
    explore: float = 0.2,
    gamma: float = 0.99,
    max_steps: int | None = None,
) -> Demonstrations:
    """Run ``teacher`` (a :class:`~rfsas_hw.envs.rl.Policy`) for ``episodes`` episodes.

    In each step the action taken is the teacher's, or with probability
    ``explore`` one drawn uniformly; the label is always the teacher's. Episode
    ``k`` is reset with a seed drawn from ``seed``, so the same arguments give
    the same demonstrations. ``gamma`` discounts the returns (PPO's). With
    ``max_steps`` no episode starts once that many steps were taken (the first
    always runs, and an episode is never cut short).

    Raises:
        ConfigError: ``episodes`` < 1, ``explore`` outside [0, 1] or ``gamma``
            outside (0, 1].
    """
    if episodes < 1:
        raise ConfigError(f"demonstrations need at least one episode, got {episodes}")
    if not 0.0 <= explore <= 1.0:
        raise ConfigError(f"explore must be a probability in [0, 1], got {explore}")
    if not 0.0 < gamma <= 1.0:
        raise ConfigError(f"gamma must be in (0, 1], got {gamma}")
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5EED]))
    env = IntersectionEnv(config)
    n_actions = int(env.action_space.n)
    obs_rows: list[npt.NDArray[np.float32]] = []
    labels: list[int] = []
    returns: list[float] = []
    run = 0
    try:
        while run < episodes and (run == 0 or max_steps is None or len(labels) < max_steps):
            run += 1
            obs, _ = env.reset(seed=int(rng.integers(0, 2**31 - 1)))
            rewards: list[float] = []
            while True:
                label = int(teacher.act(obs))
                explored = rng.uniform() < explore
                action = int(rng.integers(0, n_actions)) if explored else label
                obs_rows.append(obs)
                labels.append(label)
                obs, reward, term, trunc, _ = env.step(action)
                rewards.append(float(reward))
                if term or trunc:
                    break
            returns += _discounted(rewards, gamma)
    finally:
        env.close()
    return Demonstrations(
        np.stack(obs_rows).astype(np.float32),
        np.asarray(labels, dtype=np.int64),
        np.asarray(returns, dtype=np.float64),
        run,
    )


def _discounted(rewards: list[float], gamma: float) -> list[float]:
    """Return-to-go of every step of one episode."""
    out = [0.0] * len(rewards)
    acc = 0.0
    for i in range(len(rewards) - 1, -1, -1):
        acc = rewards[i] + gamma * acc
        out[i] = acc
    return out


def clone(
    policy: Any,
    demo: Demonstrations,
    *,
    epochs: int = 20,
    batch_size: int = 256,
    learning_rate: float = 1e-3,
    smoothing: float = 0.1,
    value_weight: float = 0.5,
    seed: int = 0,
) -> CloneStats:
    """Fit an SB3 ``ActorCriticPolicy`` (``model.policy``) to ``demo`` in place.

    Loss per minibatch: cross-entropy of the action distribution against the
    teacher's action smoothed by ``smoothing`` (``1 − smoothing`` on the
    teacher's action, the rest spread evenly over the others), plus
    ``value_weight`` times the mean squared error of the critic against the
    discounted returns. Adam with ``learning_rate`` (its own optimiser: PPO's
    is left as it was); minibatches are shuffled with ``seed``.

    Raises:
        ConfigError: ``epochs`` or ``batch_size`` < 1, or ``smoothing`` outside [0, 1).
    """
    if epochs < 1 or batch_size < 1:
        raise ConfigError(f"epochs and batch_size must be >= 1, got {epochs}, {batch_size}")
    if not 0.0 <= smoothing < 1.0:
        raise ConfigError(f"smoothing must be in [0, 1), got {smoothing}")
    import torch

    n_actions = int(policy.action_space.n)
    obs = torch.as_tensor(demo.obs, device=policy.device)
    actions = torch.as_tensor(demo.actions, device=policy.device)
    returns = torch.as_tensor(demo.returns, dtype=torch.float32, device=policy.device)
    target = torch.full((len(actions), n_actions), smoothing / max(n_actions - 1, 1))
    target[torch.arange(len(actions)), actions] = 1.0 - smoothing
    target = target.to(policy.device)
    optimiser = torch.optim.Adam(policy.parameters(), lr=learning_rate)
    rng = np.random.default_rng(seed)
    policy.set_training_mode(True)
    for _ in range(epochs):
        order = torch.as_tensor(rng.permutation(len(actions)), device=policy.device)
        for start in range(0, len(order), batch_size):
            idx = order[start : start + batch_size]
            logits = policy.get_distribution(obs[idx]).distribution.logits
            bc = -(target[idx] * torch.log_softmax(logits, dim=-1)).sum(dim=-1).mean()
            value = policy.predict_values(obs[idx]).flatten()
            loss = bc + value_weight * torch.mean((value - returns[idx]) ** 2)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
    policy.set_training_mode(False)
    with torch.no_grad():
        chosen = policy.get_distribution(obs).distribution.logits.argmax(dim=-1)
        values = policy.predict_values(obs).flatten()
    return CloneStats(
        agreement=float((chosen == actions).float().mean()),
        value_rmse=float(torch.sqrt(torch.mean((values - returns) ** 2))),
    )
