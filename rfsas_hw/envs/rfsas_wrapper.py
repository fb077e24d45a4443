"""A Gymnasium wrapper that adds RF-SAS to a driving environment.

Any env an adapter (:class:`rfsas_hw.bridges.adapter.SimAdapter`) can read
gains the RF-SAS picture: each step the adapter reads the ego and the other
entities, the :class:`~rfsas_hw.bridges.bridge.Bridge` runs the real chain
(twin radio, DF, hashing, backend), and the wrapper adds

- to the observation, the encoded assessments of
  :mod:`rfsas_hw.envs.rfsas_obs`: a ``Dict`` space ``{"env": <the env's
  observation>, "rfsas": Box(max_emitters, 11)}``, or with ``flatten=True``
  one ``Box`` (the env's observation flattened, then the rows) for
  stable-baselines3's ``MlpPolicy``;
- to ``info["rfsas"]``: the advisory and its reasons, the step's bearings
  per unit and fixes (emitter ids are keyed hashes; no MAC), whether the
  shield acted, and whether the ego collided;
- optionally a **shield**: while the advisory is BRAKE (and for ``hold_s``
  after the last BRAKE) the agent's action is replaced by the adapter's
  braking action;
- in ``render()``, the overlays of :mod:`rfsas_hw.envs.overlay` on the env's
  own RGB frames (render mode ``rgb_array``).

Seeding: ``reset(seed=s)`` seeds the env, the adapter and the bridge's
radio and MACs from ``s``; a later ``reset()`` draws the next episode's
seed from a generator seeded by ``s``, so a seeded run repeats exactly.

Example::

    import gymnasium as gym
    from rfsas_hw.bridges.highway import HighwayAdapter, require_highway
    from rfsas_hw.envs.rfsas_wrapper import RfsasWrapper

    require_highway()
    env = RfsasWrapper(gym.make("intersection-v0"), HighwayAdapter(), shield=True)
    obs, info = env.reset(seed=0)
"""

from __future__ import annotations

import importlib
from dataclasses import replace
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from rfsas_hw.bridges.adapter import SimAdapter, Snapshot
from rfsas_hw.bridges.bridge import Bridge, StepResult
from rfsas_hw.bridges.config import BridgeConfig
from rfsas_hw.envs.overlay import draw_overlay
from rfsas_hw.envs.rfsas_obs import ObsScales, encode, rfsas_space_bounds
from rfsas_hw.errors import ConfigError
from rfsas_hw.records import Pose, emitter_hex

__all__ = ["ADAPTERS", "RfsasWrapper", "make_adapter"]

_SEED_SPAN = 2**31 - 1
ADAPTERS = {
    "highway-env": "rfsas_hw.bridges.highway:HighwayAdapter",
    "metadrive": "rfsas_hw.bridges.metadrive:MetaDriveAdapter",
}
"""Adapters by name (``module:class``, imported when used)."""


def make_adapter(name: str) -> SimAdapter:
    """A fresh adapter by its :data:`ADAPTERS` name, with its defaults.

    Raises:
        ConfigError: an unknown name.
    """
    target = ADAPTERS.get(name)
    if target is None:
        raise ConfigError(f"unknown adapter {name!r} (known: {', '.join(sorted(ADAPTERS))})")
    module, _, cls = target.partition(":")
    adapter: SimAdapter = getattr(importlib.import_module(module), cls)()
    return adapter


class RfsasWrapper(
    gym.Wrapper[Any, Any, Any, Any],
    gym.utils.RecordConstructorArgs,
):
    """RF-SAS as an observation, an ``info`` entry and an optional shield (see the module
    docstring).

    Args:
        env: the driving env.
        adapter: reads ``env`` for the bridge: an adapter (e.g.
            :class:`~rfsas_hw.bridges.highway.HighwayAdapter`) or the name of one in
            :data:`ADAPTERS`, built with its defaults (a name keeps the wrapper's
            Gymnasium spec remakeable: ``env.spec.make()`` builds a fresh adapter).
        config: the bridge's units, devices and backend profile (the adapter's units
            and buildings are added each episode; default: only the ego's own unit).
        max_emitters: rows of the RF-SAS observation.
        flatten: one flat ``Box`` instead of a ``Dict`` (needs a flattenable env space).
        shield: brake on a BRAKE advisory, whatever the agent chose.
        hold_s: the shield keeps braking this long after the last BRAKE, seconds.
        scales: normalisation of the observation.
        overlay: draw the RF-SAS picture on ``render()`` frames.

    Raises:
        ConfigError: ``max_emitters`` < 1, ``hold_s`` < 0, an unknown adapter name.
    """

    def __init__(
        self,
        env: gym.Env[Any, Any],
        adapter: SimAdapter | str,
        config: BridgeConfig | None = None,
        *,
        max_emitters: int = 4,
        flatten: bool = False,
        shield: bool = False,
        hold_s: float = 1.0,
        scales: ObsScales | None = None,
        overlay: bool = True,
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self,
            adapter=adapter,
            config=config,
            max_emitters=max_emitters,
            flatten=flatten,
            shield=shield,
            hold_s=hold_s,
            scales=scales,
            overlay=overlay,
        )
        gym.Wrapper.__init__(self, env)
        if max_emitters < 1:
            raise ConfigError(f"max_emitters must be at least 1, not {max_emitters}")
        if not hold_s >= 0:
            raise ConfigError(f"hold_s must be >= 0, not {hold_s}")
        self.adapter: SimAdapter = make_adapter(adapter) if isinstance(adapter, str) else adapter
        self.config = config or BridgeConfig()
        self.max_emitters = max_emitters
        self.flatten = flatten
        self.shield = shield
        self.hold_s = hold_s
        self.scales = scales or ObsScales()
        self.overlay = overlay
        lo, hi = rfsas_space_bounds(max_emitters)
        self.rfsas_space = spaces.Box(lo, hi, dtype=np.float32)
        bounded = self.adapter.bounded_space(env)
        inner = bounded if bounded is not None else env.observation_space
        self._inner_space: spaces.Space[Any] = inner
        self._clip = bounded is not None and isinstance(bounded, spaces.Box)
        if flatten:
            flat = spaces.flatten_space(inner)
            if not isinstance(flat, spaces.Box):
                raise ConfigError(
                    f"flatten=True needs an env space that flattens to a Box, not {inner}"
                )
            self.observation_space = spaces.Box(
                np.concatenate([flat.low.astype(np.float32), lo.ravel()]),
                np.concatenate([flat.high.astype(np.float32), hi.ravel()]),
                dtype=np.float32,
            )
        else:
            self.observation_space = spaces.Dict({"env": inner, "rfsas": self.rfsas_space})
        self.bridge: Bridge | None = None
        self.last: StepResult | None = None
        """The bridge's result at the last reset or step."""
        self.snapshot: Snapshot | None = None
        self._seeds: np.random.Generator | None = None
        self._hold_until = -np.inf
        self.episode_seed: int | None = None
        """Seed of the current episode."""

    # -- observation --------------------------------------------------------------------

    def _obs(self, inner: Any, result: StepResult, snap: Snapshot) -> Any:
        rows = encode(result.assessments, snap.ego, self.max_emitters, self.scales)
        if self._clip:
            box = self._inner_space
            assert isinstance(box, spaces.Box)
            inner = np.clip(inner, box.low, box.high).astype(box.dtype)
        if self.flatten:
            flat = spaces.flatten(self._inner_space, inner)
            return np.concatenate([np.asarray(flat, np.float32), rows.ravel()])
        return {"env": inner, "rfsas": rows}

    def _info(self, result: StepResult, shielded: bool, collided: bool) -> dict[str, Any]:
        t0 = self.bridge.t0_ns if self.bridge is not None else 0
        bearings = {
            uid: [
                {
                    "t_s": (int(b.t_ns[i]) - t0) / 1e9,
                    "azimuth_deg": float(b.azimuth_deg[i]),
                    "sigma_deg": float(b.sigma_deg[i]),
                    "emitter": emitter_hex(int(b.emitter[i])),
                }
                for i in range(len(b))
            ]
            for uid, b in result.bearings.items()
        }
        return {
            "advisory": result.advisory,
            "reasons": list(result.reasons),
            "bearings": bearings,
            "fixes": [f.as_dict() for f in result.fixes],
            "tracked": len(result.assessments),
            "shielded": shielded,
            "collision": collided,
        }

    # -- episode ------------------------------------------------------------------------

    def _episode_seed(self, seed: int | None) -> int:
        if seed is not None:
            self._seeds = np.random.default_rng(seed)
            return int(seed) % _SEED_SPAN
        if self._seeds is None:
            self._seeds = np.random.default_rng()
        return int(self._seeds.integers(0, _SEED_SPAN))

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        """Reset the env, the adapter and a fresh bridge; the first RF-SAS picture is empty."""
        ep = self._episode_seed(seed)
        kwargs: dict[str, Any] = {"seed": self.adapter.env_seed(self.env, ep)}
        if options:  # MetaDrive's reset takes no options
            kwargs["options"] = options
        inner, info = self.env.reset(**kwargs)
        if self.bridge is not None:
            self.bridge.close()
        self.adapter.reset(self.env, ep)
        cfg = replace(self.config, seed=ep, units=self.config.units + tuple(self.adapter.units()))
        self.bridge = Bridge(cfg, buildings=self.adapter.buildings())
        self.episode_seed = ep
        self._hold_until = -np.inf
        snap = self.adapter.read(self.env)
        self.snapshot = snap
        self.last = self.bridge.step(snap.t_s, snap.ego, snap.entities)
        info = dict(info)
        info["rfsas"] = self._info(self.last, False, False)
        return self._obs(inner, self.last, snap), info

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        """Step the env (through the shield), then the bridge.

        Raises:
            SimulationError: step before reset, or the adapter cannot brake.
        """
        if self.bridge is None or self.last is None or self.snapshot is None:
            from rfsas_hw.errors import SimulationError

            raise SimulationError("RfsasWrapper.step before reset")
        shielded = False
        if self.shield and (self.last.advisory == "brake" or self.snapshot.t_s < self._hold_until):
            action = self.adapter.brake_action(self.env, action)
            shielded = True
        inner, reward, terminated, truncated, info = self.env.step(action)
        self.adapter.after_step(self.env)
        snap = self.adapter.read(self.env)
        self.snapshot = snap
        self.last = self.bridge.step(snap.t_s, snap.ego, snap.entities)
        if self.last.advisory == "brake":
            self._hold_until = snap.t_s + self.hold_s
        info = dict(info)
        info["rfsas"] = self._info(self.last, shielded, self.adapter.collided(self.env, info))
        return self._obs(inner, self.last, snap), reward, terminated, truncated, info

    # -- display ------------------------------------------------------------------------

    def unit_poses(self) -> dict[str, Pose]:
        """Every unit's pose at the last step (rfsas frame)."""
        out: dict[str, Pose] = {}
        if self.bridge is None or self.bridge.twin is None or self.snapshot is None:
            return out
        for uid in self.bridge.unit_ids:
            xy, heading = self.bridge.twin.sensor_pose(uid, [self.snapshot.t_s])
            out[uid] = Pose(float(xy[0, 0]), float(xy[0, 1]), float(heading[0]))
        return out

    def render(self) -> Any:
        """The env's frame, with the RF-SAS overlay when it is an RGB array."""
        frame = self.env.render()
        if not self.overlay or self.last is None or not isinstance(frame, np.ndarray):
            return frame
        if frame.ndim != 3 or frame.shape[2] != 3:
            return frame
        adapter = self.adapter
        env = self.env

        def to_px(east: Any, north: Any) -> Any:
            return adapter.to_pixels(env, east, north)

        return draw_overlay(
            frame.astype(np.uint8, copy=False),
            to_px,
            buildings=adapter.buildings(),
            units=self.unit_poses(),
            bearings=self.last.bearings,
            assessments=self.last.assessments,
        )

    def close(self) -> None:
        """Close the bridge and the env."""
        if self.bridge is not None:
            self.bridge.close()
            self.bridge = None
        super().close()
