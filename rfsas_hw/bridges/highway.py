"""The highway-env adapter: walkers and cyclists with phones for scenes without any.

highway-env (the ``highway`` extra) has vehicles only. On each reset this
adapter adds, to any highway-env scene with a road network
(``intersection-v0`` first), people who cross the ego's path from behind a
building it places beside the ego's lane:

- the crossing is ``crossing.before_end_m`` before the end of the ego's lane
  (in ``intersection-v0``: the crosswalk of its approach), or
  ``crossing.ahead_m`` ahead of the ego on long lanes;
- the building stands on the right-hand kerb just before the crossing, so a
  crosser walking in from the right is hidden from the ego until late;
- each crosser is a pedestrian or a cyclist (``crossing.cyclist_share``) who
  reaches the ego's lane when an ego holding its speed would (±
  ``crossing.jitter_s``): without braking, the ego hits them;
- two roadside units stand on the left-hand kerb, before and after the
  crossing, and see the crossers over the road (the building hides them from
  the ego and its own unit).

A crosser is a solid highway-env ``Obstacle`` (a collision crashes the ego and
ends the episode; highway-env's IDM drivers brake for it) that the adapter
moves at the policy rate. It is in the road's object list only while the ego
can see it (the segment from the ego to it does not cross the building), so a
camera-like observation of highway-env, such as ``Kinematics`` with
obstacles, sees it only when a camera could. The bridge always gets every
crosser: phones are heard through and around the building.

Coordinates go through :data:`rfsas_hw.bridges.coords.FRAMES` ``["highway-env"]``
(its ``y`` points south; the rfsas origin is highway-env's origin).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rfsas_hw.bridges.adapter import Array, Snapshot
from rfsas_hw.bridges.bridge import Entity
from rfsas_hw.bridges.config import EntityKind, UnitSpec
from rfsas_hw.bridges.coords import FRAMES
from rfsas_hw.bridges.crossing import (
    CROSSER_SIZES_M,
    Crosser,
    CrossingConfig,
    plan_crossing,
)
from rfsas_hw.errors import ConfigError, MissingDependencyError, SimulationError
from rfsas_hw.twin.rfworld import building_array, segment_crossings
from rfsas_hw.twin.scenario import BuildingSpec

__all__ = [
    "Crosser",
    "CrossingConfig",
    "HighwayAdapter",
    "idle_action",
    "make_scene",
    "require_highway",
]

FRAME = FRAMES["highway-env"]


def _rfsas_xy(xy: Array) -> tuple[float, float]:
    e, n, _ = FRAME.to_rfsas(xy[0], xy[1], 0.0)
    return float(e), float(n)


def require_highway() -> Any:
    """The ``highway_env`` module (registers its environments with Gymnasium).

    Raises:
        MissingDependencyError: highway-env is not installed (names the install command).
    """
    try:
        import highway_env
    except ImportError as err:
        raise MissingDependencyError(
            "highway-env is not installed; install it with: pip install 'rfsas-hw[highway]'"
        ) from err
    return highway_env


SCENE_ALIASES = {"intersection-v0": "rfsas/highway-intersection-v0"}
"""Ids :func:`make_scene` makes under an alias of the same entry point."""


def make_scene(
    env_id: str = "intersection-v0",
    config: dict[str, Any] | None = None,
    render_mode: str | None = None,
) -> Any:
    """A highway-env scene by its Gymnasium id, built from its entry point.

    Made with ``gymnasium.make`` (so it has a spec that the env checker can
    remake); ``intersection-v0`` is made under the alias
    ``rfsas/highway-intersection-v0`` (same entry point), because Gymnasium
    warns that highway-env has newer versions of that id.

    Raises:
        MissingDependencyError: highway-env is not installed.
        ConfigError: ``env_id`` is not a registered environment.
    """
    require_highway()
    import gymnasium as gym

    target = SCENE_ALIASES.get(env_id, env_id)
    if target not in gym.registry:
        original = gym.registry.get(env_id)
        if original is None or target == env_id:
            raise ConfigError(f"{env_id!r} is not a registered highway-env environment")
        gym.register(id=target, entry_point=original.entry_point, kwargs=original.kwargs)
    return gym.make(target, config=config or {}, render_mode=render_mode)


def idle_action(env: Any) -> Any:
    """The action that holds the ego's speed (``IDLE`` of discrete meta-actions, else zeros)."""
    at = env.unwrapped.action_type
    indexes = getattr(at, "actions_indexes", None)
    if indexes is not None and "IDLE" in indexes:
        return np.int64(indexes["IDLE"])
    return np.zeros(at.space().shape, np.float32)


@dataclass
class HighwayCrosser:
    """A planned crosser and the highway-env ``Obstacle`` standing for it."""

    plan: Crosser
    """Where it walks (highway-env coordinates)."""
    obstacle: Any = None
    """The ``Obstacle``."""

    @property
    def id(self) -> str:
        """Entity id."""
        return self.plan.id

    @property
    def kind(self) -> EntityKind:
        """``pedestrian`` or ``cyclist``."""
        return self.plan.kind

    @property
    def exit_s(self) -> float:
        """Episode time at which it has left, seconds."""
        return self.plan.exit_s

    def position(self, t_s: float) -> Array:
        """Position at episode time ``t_s``."""
        return self.plan.position(t_s)


class HighwayAdapter:
    """RF-SAS for a highway-env scene (see the module docstring).

    Args:
        crossing: the crossers, the building and where they stand.
    """

    frame_name = "highway-env"

    def __init__(self, crossing: CrossingConfig | None = None) -> None:
        self.crossing = crossing or CrossingConfig()
        self.crossers: list[HighwayCrosser] = []
        self._building: BuildingSpec | None = None
        self._units: list[UnitSpec] = []
        self._ids: dict[int, tuple[Any, str]] = {}
        self._visible: dict[str, bool] = {}

    # -- episode set-up ------------------------------------------------------------

    def env_seed(self, env: Any, seed: int) -> int:
        """``seed`` itself: highway-env seeds its random generator with it."""
        return seed

    def reset(self, env: Any, seed: int) -> None:
        """Place the building, the units and the crossers for a freshly reset ``env``.

        Raises:
            SimulationError: the env has no road network or no ego vehicle.
        """
        base = env.unwrapped
        ego = getattr(base, "vehicle", None)
        road = getattr(base, "road", None)
        if ego is None or road is None or getattr(ego, "lane", None) is None:
            raise SimulationError("highway-env: the env has no road network or no ego vehicle")
        plan = plan_crossing(ego.lane, ego.position, float(ego.speed), FRAME, self.crossing, seed)
        self._building = plan.building
        self._units = list(plan.units)
        self.crossers = [HighwayCrosser(c) for c in plan.crossers]
        self._ids = {}
        self._visible = {}
        for cr in self.crossers:
            cr.obstacle = self._obstacle(road, cr)
        self._sync(base)

    def _obstacle(self, road: Any, cr: HighwayCrosser) -> Any:
        from highway_env.vehicle.objects import Obstacle

        ob = Obstacle(road, cr.position(0.0), heading=cr.plan.heading_rad, speed=cr.plan.speed_mps)
        ob.LENGTH, ob.WIDTH = CROSSER_SIZES_M[cr.kind]
        ob.diagonal = float(np.hypot(ob.LENGTH, ob.WIDTH))
        return ob

    # -- each step ---------------------------------------------------------------------

    def after_step(self, env: Any) -> None:
        """Move the crossers to the env's time and show or hide them from the ego."""
        self._sync(env.unwrapped)

    def _sync(self, base: Any) -> None:
        t = float(base.time)
        road = base.road
        ego = base.vehicle
        rects = building_array([self._building]) if self._building is not None else None
        for cr in self.crossers:
            ob = cr.obstacle
            gone = t >= cr.exit_s
            ob.position = cr.position(t)
            seen = False
            if not gone and rects is not None:
                p0 = np.array([_rfsas_xy(ego.position)])
                p1 = np.array([_rfsas_xy(ob.position)])
                seen = not bool(segment_crossings(p0, p1, rects)[0, 0])
            self._visible[cr.id] = seen
            if seen and ob not in road.objects:
                road.objects.append(ob)
            elif not seen and ob in road.objects:
                road.objects.remove(ob)

    def visible(self, crosser_id: str) -> bool:
        """Whether the ego could see the crosser at the last step."""
        return self._visible.get(crosser_id, False)

    def _id(self, v: Any) -> str:
        key = id(v)
        known = self._ids.get(key)
        if known is None or known[0] is not v:
            known = (v, f"vehicle-{len(self._ids)}")
            self._ids[key] = known
        return known[1]

    def _entity(self, eid: str, kind: EntityKind, v: Any) -> Entity:
        return Entity.from_sim(
            FRAME,
            eid,
            kind,
            (v.position[0], v.position[1]),
            v.heading,
            speed_mps=v.speed,
            length_m=v.LENGTH,
            width_m=v.WIDTH,
        )

    def read(self, env: Any) -> Snapshot:
        """The ego, the other vehicles and the crossers still on their way."""
        base = env.unwrapped
        ego = base.vehicle
        t = float(base.time)
        others = [
            self._entity(self._id(v), "vehicle", v) for v in base.road.vehicles if v is not ego
        ]
        for cr in self.crossers:
            if t < cr.exit_s:
                others.append(self._entity(cr.id, cr.kind, cr.obstacle))
        return Snapshot(t, self._entity("ego", "vehicle", ego), tuple(others))

    def buildings(self) -> Sequence[BuildingSpec]:
        """The occluding building of this episode."""
        return [] if self._building is None else [self._building]

    def units(self) -> Sequence[UnitSpec]:
        """The two roadside units of this episode."""
        return list(self._units)

    def brake_action(self, env: Any, action: Any) -> Any:
        """An emergency stop: for discrete meta-actions the ego's target speed is set to 0 (below
        the lowest rung of scenes such as ``highway-v0``, whose ladder starts at 20 m/s) and
        ``IDLE`` is returned, so it brakes at once
        (``SLOWER`` steps the target down one rung per decision, measured from the current
        speed: from 9 m/s it keeps asking for 4.5 m/s until the ego is below 6.75 m/s);
        for continuous actions, full deceleration.

        Raises:
            SimulationError: an action type this adapter cannot brake with.
        """
        base = env.unwrapped
        at = base.action_type
        indexes = getattr(at, "actions_indexes", None)
        ego = base.vehicle
        if indexes is not None and "IDLE" in indexes and hasattr(ego, "target_speeds"):
            ego.speed_index = 0
            ego.target_speed = 0.0
            return np.int64(indexes["IDLE"])
        if getattr(at, "longitudinal", False) and hasattr(at, "space"):
            out = np.array(action, dtype=np.float32, copy=True).reshape(-1)
            out[0] = -1.0
            return out
        raise SimulationError(
            f"highway-env: cannot brake with action type {type(at).__name__} "
            "(needs DiscreteMetaAction with IDLE, or a longitudinal ContinuousAction)"
        )

    def bounded_space(self, env: Any) -> Any:
        """``Box(-1, 1)`` for a normalised, clipped ``Kinematics`` observation (highway-env
        declares ±inf although it clips every feature to [-1, 1]); None otherwise."""
        from gymnasium import spaces

        obs_type = getattr(env.unwrapped, "observation_type", None)
        features = getattr(obs_type, "features", None)
        if features is None or not (
            getattr(obs_type, "normalize", False) and getattr(obs_type, "clip", False)
        ):
            return None
        ranged = set(getattr(obs_type, "features_range", None) or {}) | {
            "presence",
            "cos_h",
            "sin_h",
        }
        if not set(features) <= ranged:
            return None
        space = env.observation_space
        return spaces.Box(-1.0, 1.0, shape=space.shape, dtype=space.dtype)

    def collided(self, env: Any, info: dict[str, Any]) -> bool:
        """Whether the ego has crashed."""
        return bool(env.unwrapped.vehicle.crashed)

    def to_pixels(self, env: Any, east_m: Array, north_m: Array) -> tuple[Array, Array] | None:
        """Pixels of rfsas points in the env's last ``rgb_array`` frame (None before one)."""
        viewer = getattr(env.unwrapped, "viewer", None)
        if viewer is None:
            return None
        surf = viewer.sim_surface
        x, y, _ = FRAME.from_rfsas(east_m, north_m, 0.0)
        return (
            np.asarray((x - surf.origin[0]) * surf.scaling, np.float64),
            np.asarray((y - surf.origin[1]) * surf.scaling, np.float64),
        )
