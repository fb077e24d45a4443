"""What a Gymnasium driving environment's adapter offers the RF-SAS wrapper.

An adapter knows one simulator: how to read its ego and entities in the
rfsas frame (through :mod:`rfsas_hw.bridges.coords`), what it lacks and must
add (walkers with phones, an occluding building), which of its actions
brakes, and how its rendered frames map to the ground. The wrapper
(:class:`rfsas_hw.envs.rfsas_wrapper.RfsasWrapper`) calls it in this order::

    obs, info = env.reset(seed=adapter.env_seed(env, s))
    adapter.reset(env, s)              # add walkers, place the occluder and units
    snap = adapter.read(env)           # -> Bridge.step(snap.t_s, snap.ego, snap.entities)
    ... each step:
    action = adapter.brake_action(env, action)   # only when the shield brakes
    obs, r, term, trunc, info = env.step(action)
    adapter.after_step(env)            # move what the simulator does not move
    snap = adapter.read(env)

Adapters are plain classes that satisfy :class:`SimAdapter` structurally.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from rfsas_hw.bridges.bridge import Entity
from rfsas_hw.bridges.config import UnitSpec
from rfsas_hw.twin.scenario import BuildingSpec

Array = npt.NDArray[np.float64]

__all__ = ["SimAdapter", "Snapshot"]


@dataclass(frozen=True)
class Snapshot:
    """The simulator's world at one moment, in the rfsas frame."""

    t_s: float
    """Simulation time, seconds since the episode began."""
    ego: Entity
    """The ego vehicle (box centre, compass heading)."""
    entities: tuple[Entity, ...]
    """Every other entity the bridge should know about (with or without a device)."""


class SimAdapter(Protocol):
    """One simulator, seen by the RF-SAS wrapper (see the module docstring)."""

    frame_name: str
    """Name of the simulator's convention in :data:`rfsas_hw.bridges.coords.FRAMES`."""

    def env_seed(self, env: Any, seed: int) -> int:
        """The seed to reset ``env`` with for the episode seed ``seed``."""

    def reset(self, env: Any, seed: int) -> None:
        """Prepare a freshly reset ``env`` (add walkers, place the occluder), seeded by ``seed``."""

    def after_step(self, env: Any) -> None:
        """Advance what the simulator does not advance by itself."""

    def read(self, env: Any) -> Snapshot:
        """The ego and the other entities now."""

    def buildings(self) -> Sequence[BuildingSpec]:
        """Occluders of this episode, rfsas frame (the bridge attenuates paths through them)."""

    def units(self) -> Sequence[UnitSpec]:
        """Roadside units this adapter places for the episode (added to the configured ones)."""

    def brake_action(self, env: Any, action: Any) -> Any:
        """The action that brakes hardest, in place of ``action``."""

    def collided(self, env: Any, info: dict[str, Any]) -> bool:
        """Whether the ego has hit anything in the step that returned ``info``."""

    def bounded_space(self, env: Any) -> Any:
        """The env's observation space with the bounds its observations really keep, when
        the env declares looser ones (None: use the env's own space)."""

    def to_pixels(self, env: Any, east_m: Array, north_m: Array) -> tuple[Array, Array] | None:
        """Pixel columns and rows of rfsas-frame points in the env's last rendered frame
        (None: the env's frames cannot be mapped to the ground)."""
