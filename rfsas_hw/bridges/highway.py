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

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rfsas_hw.bridges.adapter import Array, Snapshot
from rfsas_hw.bridges.bridge import Entity
from rfsas_hw.bridges.config import EntityKind, UnitSpec
from rfsas_hw.bridges.coords import FRAMES
from rfsas_hw.errors import ConfigError, MissingDependencyError, SimulationError
from rfsas_hw.twin.rfworld import building_array, segment_crossings
from rfsas_hw.twin.scenario import BuildingSpec, PoseSpec

__all__ = [
    "Crosser",
    "CrossingConfig",
    "HighwayAdapter",
    "idle_action",
    "make_scene",
    "require_highway",
]

FRAME = FRAMES["highway-env"]
_SIZES: dict[str, tuple[float, float]] = {"pedestrian": (0.5, 0.5), "cyclist": (1.8, 0.6)}
"""Box length and width of a crosser, metres."""


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


@dataclass(frozen=True)
class CrossingConfig:
    """Where and how people cross the ego's path (see the module docstring)."""

    count: int = 1
    """Crossers per episode; the first one is timed to meet the ego, the others follow."""
    follow_gap_s: float = 1.5
    """Time between successive crossers reaching the ego's lane, seconds."""
    cyclist_share: float = 0.5
    """Probability that a crosser is a cyclist rather than a pedestrian."""
    pedestrian_speed_mps: tuple[float, float] = (1.2, 1.7)
    """Range of a pedestrian's walking speed, m/s (uniform)."""
    cyclist_speed_mps: tuple[float, float] = (3.5, 5.5)
    """Range of a cyclist's speed, m/s (uniform)."""
    jitter_s: float = 0.3
    """Half-width of the uniform spread of the meeting time, seconds."""
    before_end_m: float = 2.0
    """Distance of the crossing before the end of the ego's lane, metres."""
    ahead_m: float = 60.0
    """Longest distance of the crossing ahead of the ego, metres (for long lanes)."""
    sidewalk_m: float = 1.5
    """Gap between the lane's right edge and the building, metres."""
    building_gap_m: float = 1.0
    """Gap between the crossing's row and the building's near face, metres."""
    building_size_m: tuple[float, float] = (40.0, 30.0)
    """Building depth along the lane and width across it, metres."""
    building_loss_db: float = 20.0
    """Radio loss of a path through the building, dB."""
    exit_m: float = 8.0
    """A crosser is removed this far past the ego lane's left edge, metres."""

    def __post_init__(self) -> None:
        if self.count < 1:
            raise ValueError("count must be at least 1")
        if not 0.0 <= self.cyclist_share <= 1.0:
            raise ValueError("cyclist_share must be in [0, 1]")
        for name in ("pedestrian_speed_mps", "cyclist_speed_mps"):
            lo, hi = getattr(self, name)
            if not 0 < lo <= hi:
                raise ValueError(f"{name} must be an increasing pair of positive speeds")
        if self.jitter_s < 0 or self.follow_gap_s < 0:
            raise ValueError("jitter_s and follow_gap_s must be >= 0")


@dataclass
class Crosser:
    """One person crossing, in highway-env coordinates."""

    id: str
    """Entity id (``crosser-0``, …)."""
    kind: EntityKind
    """``pedestrian`` or ``cyclist``."""
    start_xy: Array
    """Position at episode time 0, highway-env metres."""
    velocity_xy: Array
    """Velocity, highway-env metres per second."""
    exit_s: float
    """Episode time at which the crosser has left, seconds."""
    obstacle: Any = None
    """The highway-env ``Obstacle`` standing for it."""

    def position(self, t_s: float) -> Array:
        """Highway-env position at episode time ``t_s``."""
        return np.asarray(self.start_xy + self.velocity_xy * t_s, np.float64)

    @property
    def speed_mps(self) -> float:
        """Speed, m/s."""
        return float(np.hypot(*self.velocity_xy))

    @property
    def heading_rad(self) -> float:
        """highway-env heading (radians from ``x`` towards ``y``)."""
        return float(math.atan2(self.velocity_xy[1], self.velocity_xy[0]))


class HighwayAdapter:
    """RF-SAS for a highway-env scene (see the module docstring).

    Args:
        crossing: the crossers, the building and where they stand.
    """

    frame_name = "highway-env"

    def __init__(self, crossing: CrossingConfig | None = None) -> None:
        self.crossing = crossing or CrossingConfig()
        self.crossers: list[Crosser] = []
        self._building: BuildingSpec | None = None
        self._units: list[UnitSpec] = []
        self._ids: dict[int, tuple[Any, str]] = {}
        self._visible: dict[str, bool] = {}

    # -- episode set-up ------------------------------------------------------------

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
        c = self.crossing
        rng = np.random.default_rng([seed, 0x68776179])
        lane = ego.lane
        s_ego = float(lane.local_coordinates(ego.position)[0])
        end = float(lane.length) - c.before_end_m
        s_c = min(end, s_ego + c.ahead_m) if math.isfinite(end) else s_ego + c.ahead_m
        half = float(lane.width_at(s_c)) / 2.0

        def at(s: float, lat: float) -> Array:
            return np.asarray(lane.position(s, lat), np.float64)

        right = c.sidewalk_m + half
        depth, width = c.building_size_m
        corners = [
            at(s, lat)
            for s in (s_c - c.building_gap_m - depth, s_c - c.building_gap_m)
            for lat in (right, right + width)
        ]
        e, n, _ = FRAME.to_rfsas(
            np.array([p[0] for p in corners]), np.array([p[1] for p in corners]), 0.0
        )
        self._building = BuildingSpec(
            x_min_m=float(e.min()),
            x_max_m=float(e.max()),
            y_min_m=float(n.min()),
            y_max_m=float(n.max()),
            name="occluder",
            loss_db=c.building_loss_db,
        )
        aim = at(s_c, right)
        self._units = [
            self._unit("rsu-before", at(s_c - 8.0, -(3.0 * half + 3.0)), aim),
            self._unit("rsu-after", at(s_c + 10.0, -(3.0 * half + 3.0)), aim),
        ]
        speed = max(float(ego.speed), 1.0)
        meet_s = (s_c - s_ego) / speed
        across = at(s_c, -1.0) - at(s_c, 0.0)
        across /= np.linalg.norm(across)
        self.crossers = []
        for k in range(c.count):
            cyclist = bool(rng.random() < c.cyclist_share)
            kind: EntityKind = "cyclist" if cyclist else "pedestrian"
            lo, hi = c.cyclist_speed_mps if cyclist else c.pedestrian_speed_mps
            v = float(rng.uniform(lo, hi))
            t_meet = meet_s + k * c.follow_gap_s + float(rng.uniform(-c.jitter_s, c.jitter_s))
            start = at(s_c, 0.0) - across * v * t_meet
            travel = v * t_meet + half + c.exit_m
            self.crossers.append(Crosser(f"crosser-{k}", kind, start, across * v, travel / v))
        self._ids = {}
        self._visible = {}
        for cr in self.crossers:
            cr.obstacle = self._obstacle(road, cr)
        self._sync(base)

    def _unit(self, uid: str, xy: Array, aim: Array) -> UnitSpec:
        e, n, _ = FRAME.to_rfsas(xy[0], xy[1], 0.0)
        ae, an, _ = FRAME.to_rfsas(aim[0], aim[1], 0.0)
        heading = math.degrees(math.atan2(float(ae - e), float(an - n))) % 360.0
        return UnitSpec(id=uid, pose=PoseSpec(x_m=float(e), y_m=float(n), heading_deg=heading))

    def _obstacle(self, road: Any, cr: Crosser) -> Any:
        from highway_env.vehicle.objects import Obstacle

        ob = Obstacle(road, cr.position(0.0), heading=cr.heading_rad, speed=cr.speed_mps)
        ob.LENGTH, ob.WIDTH = _SIZES[cr.kind]
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
        e, n, h = FRAME.to_rfsas(v.position[0], v.position[1], v.heading)
        return Entity(
            id=eid,
            kind=kind,
            x_m=float(e),
            y_m=float(n),
            heading_deg=float(h),
            speed_mps=float(v.speed),
            length_m=float(v.LENGTH),
            width_m=float(v.WIDTH),
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
        """``SLOWER`` for discrete meta-actions; full deceleration for continuous ones.

        Raises:
            SimulationError: an action type this adapter cannot brake with.
        """
        at = env.unwrapped.action_type
        indexes = getattr(at, "actions_indexes", None)
        if indexes is not None and "SLOWER" in indexes:
            return np.int64(indexes["SLOWER"])
        if getattr(at, "longitudinal", False) and hasattr(at, "space"):
            out = np.array(action, dtype=np.float32, copy=True).reshape(-1)
            out[0] = -1.0
            return out
        raise SimulationError(
            f"highway-env: cannot brake with action type {type(at).__name__} "
            "(needs DiscreteMetaAction with SLOWER, or a longitudinal ContinuousAction)"
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
