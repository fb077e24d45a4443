"""People crossing the ego's path from behind a building, planned on the ego's lane.

Simulators without pedestrians (highway-env) or without a pedestrian
manager that aims at the ego (MetaDrive) get the same episode from
:func:`plan_crossing`, which needs only the lane API the two share
(``position(s, lateral)``, ``local_coordinates``, ``width_at``, ``length``)
and the simulator's :class:`~rfsas_hw.bridges.coords.SimFrame`:

- the crossing is ``before_end_m`` before the end of the ego's lane (the
  crosswalk of an intersection approach), at most ``ahead_m`` ahead of the ego;
- a building stands on the right-hand kerb just before the crossing, so a
  crosser coming from the right is hidden from the ego until late;
- each crosser is a pedestrian or a cyclist (``cyclist_share``), timed to
  reach the ego's lane when an ego holding its speed would (±
  ``jitter_s``; followers ``follow_gap_s`` apart): without braking, the ego
  hits the first one;
- two roadside units stand past the crossing, one on each side of the road:
  5 m past it and 3·lane width/2 + 3 m left of the lane centre, aimed at the
  kerb where the crossers come out; 6 m past it and 20 m right, aimed 8 m
  beyond that kerb, so it sees their whole approach: the building hides
  nothing from them, and their bearings cross at a useful angle.

Which lateral side is "right" differs between simulators (highway-env's
``y`` points south); it is found from the frame, not assumed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rfsas_hw.bridges.adapter import Array
from rfsas_hw.bridges.config import EntityKind, UnitSpec
from rfsas_hw.bridges.coords import SimFrame
from rfsas_hw.twin.scenario import BuildingSpec, PoseSpec

CROSSER_SIZES_M: dict[str, tuple[float, float]] = {
    "pedestrian": (0.5, 0.5),
    "cyclist": (1.8, 0.6),
}
"""Box length and width of a crosser, metres."""

__all__ = ["CROSSER_SIZES_M", "Crosser", "CrossingConfig", "CrossingPlan", "plan_crossing"]


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
    min_ahead_m: float = 20.0
    """Shortest distance of the crossing ahead of the ego, metres."""
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
        if not 0 < self.min_ahead_m <= self.ahead_m:
            raise ValueError("need 0 < min_ahead_m <= ahead_m")


@dataclass(frozen=True)
class Crosser:
    """One person crossing, in the simulator's coordinates."""

    id: str
    """Entity id (``crosser-0``, …)."""
    kind: EntityKind
    """``pedestrian`` or ``cyclist``."""
    start_xy: Array
    """Position at episode time 0, simulator metres."""
    velocity_xy: Array
    """Velocity, simulator metres per second."""
    exit_s: float
    """Episode time at which the crosser has left, seconds."""

    def position(self, t_s: float) -> Array:
        """Simulator position at episode time ``t_s``."""
        return np.asarray(self.start_xy + self.velocity_xy * t_s, np.float64)

    @property
    def speed_mps(self) -> float:
        """Speed, m/s."""
        return float(np.hypot(*self.velocity_xy))

    @property
    def heading_rad(self) -> float:
        """Direction of travel, radians from the simulator's ``x`` towards its ``y``
        (highway-env's ``heading`` and MetaDrive's ``heading_theta`` alike)."""
        return float(math.atan2(self.velocity_xy[1], self.velocity_xy[0]))


@dataclass(frozen=True)
class CrossingPlan:
    """One episode's building, units and crossers."""

    building: BuildingSpec
    """The occluder, rfsas frame."""
    units: tuple[UnitSpec, ...]
    """Roadside units, rfsas frame."""
    crossers: tuple[Crosser, ...]
    """The crossers, simulator frame."""
    crossing_xy: Array
    """Where the crossing meets the ego lane's centre, simulator metres."""


def _rfsas(frame: SimFrame, xy: Sequence[float] | Array) -> tuple[float, float]:
    e, n, _ = frame.to_rfsas(xy[0], xy[1], 0.0)
    return float(e), float(n)


def plan_crossing(
    lane: Any,
    ego_xy: Sequence[float] | Array,
    ego_speed_mps: float,
    frame: SimFrame,
    config: CrossingConfig,
    seed: int,
) -> CrossingPlan:
    """Plan the crossing on ``lane`` for an ego at ``ego_xy`` (see the module docstring).

    Args:
        lane: the ego's lane (highway-env or MetaDrive lane object).
        ego_xy: the ego's position, simulator metres.
        ego_speed_mps: the ego's speed, m/s (below 1 m/s counts as 1 m/s).
        frame: the simulator's coordinate convention.
        config: the crossing's settings.
        seed: seeds the crossers' kinds, speeds and timing.
    """
    c = config
    rng = np.random.default_rng([seed, 0x63726F73])
    s_ego = float(lane.local_coordinates(np.asarray(ego_xy, np.float64))[0])
    end = float(lane.length) - c.before_end_m
    s_c = s_ego + c.ahead_m
    if math.isfinite(end):
        s_c = min(end, s_c)
    s_c = max(s_c, s_ego + c.min_ahead_m)
    half = float(lane.width_at(s_c)) / 2.0

    def at(s: float, lat: float) -> Array:
        return np.asarray(lane.position(s, lat), np.float64)

    # which lateral sign is the ego's right: the cross product of the travel direction
    # and the +lateral offset, in the rfsas frame (east-north, right-handed)
    p0, p_fwd, p_lat = (
        _rfsas(frame, at(s, lat)) for s, lat in ((s_c, 0.0), (s_c + 1, 0.0), (s_c, 1.0))
    )
    fwd = (p_fwd[0] - p0[0], p_fwd[1] - p0[1])
    lat = (p_lat[0] - p0[0], p_lat[1] - p0[1])
    right = 1.0 if fwd[0] * lat[1] - fwd[1] * lat[0] < 0 else -1.0
    kerb = right * (c.sidewalk_m + half)
    depth, width = c.building_size_m
    corners = [
        _rfsas(frame, at(s, off))
        for s in (s_c - c.building_gap_m - depth, s_c - c.building_gap_m)
        for off in (kerb, kerb + right * width)
    ]
    building = BuildingSpec(
        x_min_m=min(p[0] for p in corners),
        x_max_m=max(p[0] for p in corners),
        y_min_m=min(p[1] for p in corners),
        y_max_m=max(p[1] for p in corners),
        name="occluder",
        loss_db=c.building_loss_db,
    )
    aim = _rfsas(frame, at(s_c, kerb))
    approach = _rfsas(frame, at(s_c, kerb + right * 8.0))

    def unit(uid: str, s: float, offset: float, aim: tuple[float, float]) -> UnitSpec:
        x, y = _rfsas(frame, at(s, offset))
        heading = math.degrees(math.atan2(aim[0] - x, aim[1] - y)) % 360.0
        return UnitSpec(id=uid, pose=PoseSpec(x_m=x, y_m=y, heading_deg=heading))

    meet_s = (s_c - s_ego) / max(ego_speed_mps, 1.0)
    across = at(s_c, -right) - at(s_c, 0.0)
    across /= np.linalg.norm(across)
    crossers = []
    for k in range(c.count):
        cyclist = bool(rng.random() < c.cyclist_share)
        kind: EntityKind = "cyclist" if cyclist else "pedestrian"
        lo, hi = c.cyclist_speed_mps if cyclist else c.pedestrian_speed_mps
        v = float(rng.uniform(lo, hi))
        t_meet = meet_s + k * c.follow_gap_s + float(rng.uniform(-c.jitter_s, c.jitter_s))
        start = at(s_c, 0.0) - across * v * t_meet
        travel = v * t_meet + half + c.exit_m
        crossers.append(Crosser(f"crosser-{k}", kind, start, across * v, travel / v))
    return CrossingPlan(
        building,
        (
            unit("rsu-left", s_c + 5.0, -right * (3.0 * half + 3.0), aim),
            unit("rsu-right", s_c + 6.0, right * 20.0, approach),
        ),
        tuple(crossers),
        at(s_c, 0.0),
    )
