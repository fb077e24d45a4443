"""Named training set-ups: what ``rfsas sim train`` and ``evaluate`` use without options.

A :class:`Preset` fixes the parts of a learning run that decide whether it
works: the reward, the episodes (scenario), whether the RF activity prior is
observed, the number of vectorised environments, the PPO settings and the
step budget.

- ``protocol`` (the default): the configuration that the multi-seed protocol
  (docs/simulation.md §10) found to give learned risk at or below the rule's
  at every reaction distance: the ``risk-progress`` reward, quiet and busy
  corners, no prior, the risk of driving on observed (``observe_drive_on``:
  what the backend would estimate if the car drove on now at its initial
  speed, so that a car stopped for a warning sees when the crosser has
  passed), 8 environments, PPO n_steps 128 per environment, batch 256,
  entropy 0.01.
- ``method``: method.md §10 as written: the ``method`` reward, the single
  crosser, no drive-on entries, one environment, PPO n_steps 64, batch 64, entropy 0
  (:data:`rfsas_hw.envs.rl.PPO_DEFAULTS`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from rfsas_hw.envs.envconfig import EnvConfig, RewardKind, ScenarioKind
from rfsas_hw.envs.rl import PPO_DEFAULTS
from rfsas_hw.errors import ConfigError

__all__ = ["DEFAULT_PRESET", "PRESETS", "Preset", "preset"]


@dataclass(frozen=True)
class Preset:
    """A training and evaluation set-up (see the module docstring)."""

    name: str
    """Name on the command line (``--preset``)."""
    reward: RewardKind
    """Reward the agent is trained with (``reward.kind``)."""
    scenario: ScenarioKind
    """Episodes drawn by ``reset`` (``scenario.kind``)."""
    prior: bool
    """Whether the RF activity prior is in the observation (``prior.observe``)."""
    n_envs: int
    """Environments stepped side by side during training."""
    steps: int
    """Environment steps of one training run."""
    ppo: Mapping[str, Any] = field(default_factory=dict)
    """PPO hyper-parameters (``n_steps`` is per environment)."""
    drive_on: bool = False
    """Whether the risk of driving on is in the observation (``observe_drive_on``)."""

    def apply(self, config: EnvConfig) -> EnvConfig:
        """``config`` with this preset's reward, scenario and prior."""
        return dataclasses.replace(
            config,
            reward=dataclasses.replace(config.reward, kind=self.reward),
            scenario=dataclasses.replace(config.scenario, kind=self.scenario),
            prior=dataclasses.replace(config.prior, observe=self.prior),
            observe_drive_on=self.drive_on,
        )


PRESETS: dict[str, Preset] = {
    "protocol": Preset(
        name="protocol",
        reward="risk-progress",
        scenario="corners",
        prior=False,
        n_envs=8,
        steps=150_000,
        ppo={**PPO_DEFAULTS, "n_steps": 128, "batch_size": 256, "ent_coef": 0.01},
        drive_on=True,
    ),
    "method": Preset(
        name="method",
        reward="method",
        scenario="single",
        prior=False,
        n_envs=1,
        steps=40_000,
        ppo=dict(PPO_DEFAULTS),
    ),
}
"""The presets by name."""

DEFAULT_PRESET = "protocol"
"""What the command line uses without ``--preset``."""


def preset(name: str) -> Preset:
    """The preset called ``name``.

    Raises:
        ConfigError: no preset has that name.
    """
    try:
        return PRESETS[name]
    except KeyError:
        raise ConfigError(
            f"unknown preset {name!r} (known: {', '.join(sorted(PRESETS))})"
        ) from None
