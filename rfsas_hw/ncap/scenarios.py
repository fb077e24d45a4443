"""The Euro NCAP VRU test matrix as planned target paths on a straight road.

Frame (SUMO's net coordinates = the rfsas frame, metres): the vehicle under
test (VUT) drives east (+x, compass 90°) along ``y = 0``, the centre of its
3.5 m lane; right-hand traffic, so the nearside (kerb side) is south
(``y < 0``) and the farside lane is centred at ``y = +3.5``. Crossing targets
cross the line ``x = 0`` (:data:`PATH_X_M`); longitudinal targets move east
ahead of the VUT.

Impact location: a fraction of the VUT's width measured from its right
(nearside) edge, so 25 % is 0.45 m from the right edge of a 1.8 m wide car.
The paths are synchronised (the protocol's principle) so that, with no
braking, the target's reference point (its box centre) is at the impact
location at the moment of first contact between the VUT's front and the
target's box. Crossing targets move at constant speed from their start (the
protocol's acceleration phase is not modelled); a target whose path is
shorter than the run's lead time waits at its start until it has to go.

Dimensions the public protocol text does not give (its figures are images)
are chosen here and marked "chosen" in :data:`SCENARIOS` and docs/ncap.md.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Literal

from rfsas_hw.errors import ConfigError

KMH = 1 / 3.6
"""m/s per km/h."""
VUT_LENGTH_M = 4.5
"""VUT length, metres (chosen: a mid-size car)."""
VUT_WIDTH_M = 1.8
"""VUT width, metres (chosen)."""
LANE_WIDTH_M = 3.5
"""Lane width, metres (chosen)."""
PATH_X_M = 0.0
"""Where crossing targets cross the VUT's lane, metres east."""
LEAD_S = 5.0
"""The VUT starts this long (at its test speed) before the planned contact, seconds."""
PARKED_GAP_TO_VUT_M = 1.0
"""Lateral gap between the VUT's side and the parked obstruction vehicles, metres (chosen)."""
PARKED_LOSS_DB = 10.0
"""Extra radio loss through a parked car, dB (chosen; see docs/ncap.md)."""
VAN_LOSS_DB = 12.0
"""Extra radio loss through a parked van, dB (chosen; see docs/ncap.md)."""
TURN_RADII_M = {10.0: 9.0, 15.0: 11.75, 20.0: 14.5}
"""Radius of the turning VUT's path (its box centre) per VUT speed, metres (chosen; see
docs/ncap.md)."""
TURN_CROSSING_M = 4.0
"""Turning scenarios: the target's crossing line lies this far beyond the end of the VUT's
turn, along the side street, metres (chosen: contact on the side street's straight)."""
TURN_LEAD_S = 8.0
"""Turning scenarios: the VUT starts this long before the planned contact (the approach,
the turn and the side street fit in it at every turning speed), seconds."""

TargetKind = Literal["pedestrian", "cyclist"]
Motion = Literal["cross", "along", "turn"]

__all__ = [
    "SCENARIOS",
    "TRUE_NEGATIVES",
    "Cell",
    "Obstacle",
    "Scenario",
    "Target",
    "TargetPath",
    "VutPath",
    "cells",
    "plan",
]


@dataclass(frozen=True)
class Target:
    """A target dummy: its box and speed."""

    kind: TargetKind
    speed_kmh: float
    length_m: float
    """Along its heading, metres."""
    width_m: float
    """Across its heading, metres."""


ADULT = (0.30, 0.50)
"""Adult pedestrian target box, length × width, metres (chosen: torso depth × shoulder width)."""
CHILD = (0.25, 0.35)
"""Child pedestrian target box, metres (chosen)."""
BICYCLE = (1.80, 0.60)
"""Bicyclist target box, metres (chosen: a bicycle's length × handlebar width)."""


@dataclass(frozen=True)
class Obstacle:
    """A parked vehicle: an axis-aligned rectangle that blocks sight and attenuates radio."""

    name: str
    x_min_m: float
    x_max_m: float
    y_min_m: float
    y_max_m: float
    loss_db: float


@dataclass(frozen=True)
class Scenario:
    """One scenario of the matrix (or a true negative)."""

    name: str
    description: str
    kind: TargetKind
    speed_kmh: float
    """Target speed, km/h."""
    motion: Motion
    """``cross`` (perpendicular to the VUT), ``along`` (ahead in the lane, same direction) or
    ``turn`` (the VUT turns into a side street; the target crosses the side street)."""
    side: Literal["near", "far", "lane"] = "near"
    """Where the target comes from; for ``turn`` the side the VUT turns to (``near``: right,
    ``far``: left, across the oncoming lane)."""
    impacts: tuple[float, ...] = (0.5,)
    """Impact locations, fraction of the VUT width from its right edge."""
    vut_speeds_kmh: tuple[float, ...] = (10, 20, 30, 40, 50, 60)
    start_offset_m: float = 6.0
    """Crossing: how far from the VUT's centre line the target starts, metres."""
    obstructed: bool = False
    """Two parked vehicles on the nearside hide the target's start."""
    child: bool = False
    points: float = 1.0
    """The protocol's points for the scenario (see docs/ncap.md)."""
    true_negative: bool = False
    """No contact is planned; any BRAKE is a nuisance."""

    @property
    def target(self) -> Target:
        """The target dummy."""
        length, width = BICYCLE if self.kind == "cyclist" else CHILD if self.child else ADULT
        return Target(self.kind, self.speed_kmh, length, width)


def _crossing(name: str, desc: str, kind: TargetKind, v: float, **kw: object) -> Scenario:
    return Scenario(name, desc, kind, v, "cross", **kw)  # type: ignore[arg-type]


SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        _crossing("CPNA", "adult walks in from the nearside", "pedestrian", 5.0,
                  impacts=(0.25, 0.75), start_offset_m=6.0, points=1.0),
        _crossing("CPFA", "adult runs in from the farside", "pedestrian", 8.0, side="far",
                  impacts=(0.5,), start_offset_m=7.5, points=1.0),
        _crossing("CPNCO", "child runs out from behind two parked vehicles", "pedestrian", 5.0,
                  impacts=(0.25, 0.5, 0.75), start_offset_m=4.3, obstructed=True, child=True,
                  points=2.0),
        Scenario("CPLA", "adult walks ahead in the VUT's lane", "pedestrian", 5.0, "along",
                 side="lane", impacts=(0.25, 0.5), points=2.0),
        _crossing("CBNA", "bicyclist rides in from the nearside", "cyclist", 15.0,
                  impacts=(0.5,), start_offset_m=17.0, points=1.0),
        _crossing("CBNAO", "bicyclist rides out from behind parked vehicles", "cyclist", 10.0,
                  impacts=(0.5,), start_offset_m=4.9, obstructed=True, points=2.0),
        _crossing("CBFA", "bicyclist rides in from the farside", "cyclist", 20.0, side="far",
                  impacts=(0.5,), start_offset_m=23.0, points=1.0),
        Scenario("CBLA", "bicyclist ahead in the VUT's lane", "cyclist", 15.0, "along",
                 side="lane", impacts=(0.5,), vut_speeds_kmh=(20, 30, 40, 50, 60), points=2.0),
        Scenario("CPTA", "VUT turns left into an adult crossing the side street towards it",
                 "pedestrian", 5.0, "turn", side="far", impacts=(0.5,),
                 vut_speeds_kmh=(10, 15, 20), start_offset_m=4.0, points=2.0),
        Scenario("CBTA", "VUT turns right across a bicyclist riding straight on beside it",
                 "cyclist", 15.0, "turn", side="near", impacts=(0.5,),
                 vut_speeds_kmh=(10, 15, 20), start_offset_m=17.0, points=2.0),
    )
}  # fmt: skip
"""The matrix (points: docs/ncap.md; CPNA/CPFA day only; CPTA/CBTA: the protocol's turning
cases, scored by avoidance only)."""

TRUE_NEGATIVES: dict[str, Scenario] = {
    s.name: s
    for s in (
        Scenario("TN-ALONG", "adult walks along the nearside sidewalk", "pedestrian", 5.0,
                 "along", side="near", true_negative=True),
        Scenario("TN-KERB", "adult walks to the kerb and stops", "pedestrian", 5.0, "cross",
                 true_negative=True, start_offset_m=6.0),
        Scenario("TN-BEHIND", "adult crosses behind the VUT after it passed", "pedestrian", 5.0,
                 "cross", true_negative=True, start_offset_m=4.0),
        Scenario("TN-BIKELANE", "bicyclist on a bike lane beside the VUT", "cyclist", 15.0,
                 "along", side="near", true_negative=True),
        Scenario("TN-PHONES", "four people with phones on the nearside sidewalk", "pedestrian",
                 1.0, "along", side="near", true_negative=True),
    )
}  # fmt: skip
"""True-negative scenarios: no contact; any BRAKE counts as a nuisance."""

SIDEWALK_Y_M = -(LANE_WIDTH_M / 2 + 2.3)
"""Centre of the nearside sidewalk, metres (chosen: beyond a 2 m parking strip)."""
KERB_STOP_Y_M = -(LANE_WIDTH_M / 2 + 0.5)
"""Where the kerb-stop walker stops: 0.5 m short of the lane edge, metres."""
BIKE_LANE_Y_M = -(LANE_WIDTH_M / 2 + 0.75)
"""Centre of a 1.5 m bike lane beside the VUT's lane, metres."""


def scenario(name: str) -> Scenario:
    """The scenario or true negative called ``name``.

    Raises:
        KeyError: unknown name (the message lists the known ones).
    """
    found = SCENARIOS.get(name) or TRUE_NEGATIVES.get(name)
    if found is None:
        known = ", ".join([*SCENARIOS, *TRUE_NEGATIVES])
        raise KeyError(f"unknown scenario {name!r} (known: {known})")
    return found


@dataclass(frozen=True)
class Cell:
    """One cell: a scenario at one VUT speed and one impact location."""

    scenario: str
    vut_speed_kmh: float
    impact: float
    """Fraction of the VUT width from its right edge (true negatives: 0.5, unused)."""

    @property
    def key(self) -> str:
        """``CPNCO-50@30``: a stable name."""
        return f"{self.scenario}-{round(self.impact * 100)}@{self.vut_speed_kmh:g}"


def cells(names: Iterable[str], speeds_kmh: Sequence[float] | None = None) -> list[Cell]:
    """Every cell of the named scenarios, at ``speeds_kmh`` (None: each scenario's own speeds;
    speeds a scenario does not test, e.g. 10 km/h for CBLA, are left out).

    Raises:
        KeyError: an unknown scenario.
        ConfigError: no scenario, an empty ``speeds_kmh``, or a speed that none of the
            named scenarios tests (the message lists the speeds they test).
    """
    chosen = [scenario(name) for name in names]
    if not chosen:
        raise ConfigError("scenarios: none chosen")
    if speeds_kmh is not None:
        tested = sorted({float(v) for s in chosen for v in s.vut_speeds_kmh})
        untested = [v for v in speeds_kmh if v not in tested]
        if untested or not speeds_kmh:
            which = ", ".join(s.name for s in chosen)
            asked = ", ".join(f"{v:g}" for v in untested)
            raise ConfigError(
                (f"speeds: {asked} km/h: not a VUT speed of {which}" if asked else "speeds: none")
                + f" ({which} tested at {', '.join(f'{v:g}' for v in tested)} km/h)"
            )
    out = []
    for s in chosen:
        name = s.name
        speeds = [v for v in s.vut_speeds_kmh if speeds_kmh is None or v in speeds_kmh]
        for v in speeds:
            for f in s.impacts:
                out.append(Cell(name, float(v), f))
    return out


@dataclass(frozen=True)
class TargetPath:
    """Where one target is at any time: piecewise constant-velocity legs."""

    id: str
    kind: TargetKind
    length_m: float
    width_m: float
    legs: tuple[tuple[float, float, float, float, float], ...]
    """``(t_start_s, x_m, y_m, vx_mps, vy_mps)``: from ``t_start_s`` on (until the next leg)
    the target is at ``(x, y) + v (t - t_start)``."""
    heading_deg: float
    """Compass heading of travel (kept while standing)."""

    def at(self, t_s: float) -> tuple[float, float, float]:
        """Box centre (x, y) and speed at ``t_s``."""
        leg = self.legs[0]
        for cand in self.legs:
            if cand[0] <= t_s:
                leg = cand
        t0, x, y, vx, vy = leg
        dt = max(t_s - t0, 0.0)
        return x + vx * dt, y + vy * dt, math.hypot(vx, vy)


@dataclass(frozen=True)
class VutPath:
    """A turning VUT's path (its box centre): east along ``y = 0`` from ``start_x_m`` to
    ``arc_x_m``, a quarter circle of ``radius_m`` to the right (``sign`` +1, ending southbound)
    or to the left (``sign`` −1, northbound), then straight on along ``x = arc_x_m +
    radius_m``."""

    start_x_m: float
    arc_x_m: float
    radius_m: float
    sign: float

    def pose(self, s_m: float) -> tuple[float, float, float]:
        """Box centre (x, y) and compass heading, degrees, after ``s_m`` metres of path."""
        r = self.radius_m
        d = s_m - (self.arc_x_m - self.start_x_m)
        if d <= 0:
            return self.start_x_m + s_m, 0.0, 90.0
        arc = math.pi / 2 * r
        if d < arc:
            th = d / r
            return (
                self.arc_x_m + r * math.sin(th),
                self.sign * (r * math.cos(th) - r),
                (90.0 + self.sign * math.degrees(th)),
            )
        return self.arc_x_m + r, -self.sign * (r + d - arc), 90.0 + self.sign * 90.0


@dataclass(frozen=True)
class Plan:
    """A cell made concrete: VUT start, target paths, parked vehicles."""

    cell: Cell
    vut_start_x_m: float
    """VUT box centre at t = 0, metres east."""
    vut_speed_mps: float
    contact_t_s: float
    """Planned first contact with no braking (true negatives: when the VUT passes x = 0)."""
    targets: tuple[TargetPath, ...]
    obstacles: tuple[Obstacle, ...] = field(default_factory=tuple)
    relative_speed: bool = False
    """Impact speed counts relative to the target (longitudinal scenarios)."""
    vut_path: VutPath | None = None
    """The turning VUT's path (None: straight east along ``y = 0``)."""


def _obstacles() -> tuple[Obstacle, ...]:
    """Two parked vehicles upstream of the crossing path: the smaller (a car, 4.0 × 1.7 m)
    nearest the path, 1.0 m before it; the larger (a van, 5.0 × 2.0 m) 1.0 m behind the car
    (chosen). Their inner sides are 1.0 m from the VUT's side."""
    inner = -(VUT_WIDTH_M / 2 + PARKED_GAP_TO_VUT_M)
    car_front = PATH_X_M - 1.0
    car = Obstacle("parked-car", car_front - 4.0, car_front, inner - 1.7, inner, PARKED_LOSS_DB)
    van_front = car.x_min_m - 1.0
    van = Obstacle("parked-van", van_front - 5.0, van_front, inner - 2.0, inner, VAN_LOSS_DB)
    return (car, van)


def plan(cell: Cell) -> Plan:
    """The paths of ``cell`` (see the module docstring).

    Raises:
        KeyError: an unknown scenario.
    """
    s = scenario(cell.scenario)
    tgt = s.target
    v_car = cell.vut_speed_kmh * KMH
    v_t = tgt.speed_kmh * KMH
    half_car = VUT_LENGTH_M / 2
    y_imp = -VUT_WIDTH_M / 2 + cell.impact * VUT_WIDTH_M
    t_c = LEAD_S
    obstacles = _obstacles() if s.obstructed else ()
    if s.true_negative:
        return _true_negative(s, cell, v_car, t_c)
    if s.motion == "turn":
        return _turning(s, cell, v_car, y_imp)
    if s.motion == "cross":
        sign = 1.0 if s.side == "near" else -1.0  # +1: moving north, from the nearside
        # contact: the VUT's front reaches the target's west side as its centre is at y_imp
        front_x = PATH_X_M - tgt.width_m / 2
        start_x = front_x - half_car - v_car * t_c
        y0 = -sign * s.start_offset_m
        walk_s = abs(y_imp - y0) / v_t
        go = t_c - walk_s
        legs: list[tuple[float, float, float, float, float]] = []
        if go > 0:
            legs.append((0.0, PATH_X_M, y0, 0.0, 0.0))
            legs.append((go, PATH_X_M, y0, 0.0, sign * v_t))
        else:
            legs.append((0.0, PATH_X_M, y0 - sign * v_t * go, 0.0, sign * v_t))
        heading = 0.0 if sign > 0 else 180.0
        path = TargetPath("target", s.kind, tgt.length_m, tgt.width_m, tuple(legs), heading)
        return Plan(cell, start_x, v_car, t_c, (path,), obstacles)
    # along: the VUT's front meets the target's rear at t_c, 'LEAD_S' after the start
    rear0 = PATH_X_M
    centre0 = rear0 + tgt.length_m / 2 - v_t * t_c  # at t = 0
    start_x = rear0 - v_car * t_c - half_car
    path = TargetPath(
        "target",
        s.kind,
        tgt.length_m,
        tgt.width_m,
        ((0.0, centre0, y_imp, v_t, 0.0),),
        90.0,
    )
    return Plan(cell, start_x, v_car, t_c, (path,), obstacles, relative_speed=True)


def _turning(s: Scenario, cell: Cell, v_car: float, y_imp: float) -> Plan:
    """The VUT turns (right for ``near``, left for ``far``) into a side street along
    ``x = PATH_X_M``; the target crosses it from the VUT's right on the line
    :data:`TURN_CROSSING_M` beyond the end of the turn, synchronised as a crossing."""
    tgt = s.target
    try:
        r = TURN_RADII_M[cell.vut_speed_kmh]
    except KeyError:
        known = ", ".join(f"{v:g}" for v in TURN_RADII_M)
        raise KeyError(
            f"{s.name}: no turning path at {cell.vut_speed_kmh:g} km/h (known: {known})"
        ) from None
    sign = 1.0 if s.side == "near" else -1.0
    h = math.radians(90.0 + sign * 90.0)  # heading after the turn
    right = (math.cos(h), -math.sin(h))
    c0 = (PATH_X_M, -sign * (r + TURN_CROSSING_M))  # crossing line ∩ the VUT's centre line
    t_c = TURN_LEAD_S
    # contact: the VUT's front reaches the target's near side as its centre is at the impact
    # location, i.e. y_imp to the left of the VUT's centre line (-y_imp along 'right')
    after = TURN_CROSSING_M - VUT_LENGTH_M / 2 - tgt.width_m / 2  # straight after the arc
    approach = v_car * t_c - math.pi / 2 * r - after
    arc_x = PATH_X_M - r
    path = VutPath(arc_x - approach, arc_x, r, sign)
    lat_imp = -y_imp
    walk_s = (s.start_offset_m - lat_imp) / (tgt.speed_kmh * KMH)
    v_t = tgt.speed_kmh * KMH
    vx, vy = -right[0] * v_t, -right[1] * v_t

    def at(lat: float) -> tuple[float, float]:
        return c0[0] + right[0] * lat, c0[1] + right[1] * lat

    go = t_c - walk_s
    legs: list[tuple[float, float, float, float, float]] = []
    if go > 0:
        x0, y0 = at(s.start_offset_m)
        legs += [(0.0, x0, y0, 0.0, 0.0), (go, x0, y0, vx, vy)]
    else:
        x0, y0 = at(s.start_offset_m - go * v_t)
        legs.append((0.0, x0, y0, vx, vy))
    heading = (sign * 90.0) % 360.0  # along -right: east after a right turn, else west
    target = TargetPath("target", s.kind, tgt.length_m, tgt.width_m, tuple(legs), heading)
    return Plan(cell, path.start_x_m, v_car, t_c, (target,), (), vut_path=path)


def _true_negative(s: Scenario, cell: Cell, v_car: float, t_c: float) -> Plan:
    tgt = s.target
    half_car = VUT_LENGTH_M / 2
    start_x = PATH_X_M - half_car - v_car * t_c  # front at x = 0 at t_c
    v_t = s.speed_kmh * KMH
    paths: list[TargetPath] = []
    if s.name == "TN-ALONG":
        legs = ((0.0, PATH_X_M - 10.0, SIDEWALK_Y_M, v_t, 0.0),)
        paths.append(TargetPath("walker", s.kind, tgt.length_m, tgt.width_m, legs, 90.0))
    elif s.name == "TN-BIKELANE":
        legs = ((0.0, PATH_X_M - 15.0, BIKE_LANE_Y_M, v_t, 0.0),)
        paths.append(TargetPath("rider", s.kind, tgt.length_m, tgt.width_m, legs, 90.0))
    elif s.name == "TN-KERB":
        # walks north from the sidewalk and stops at the kerb 3 s before the VUT arrives
        y0, y1 = -s.start_offset_m, KERB_STOP_Y_M
        stop = t_c - 3.0
        go = stop - (y1 - y0) / v_t
        legs2 = (
            (0.0, PATH_X_M, y0, 0.0, 0.0),
            (go, PATH_X_M, y0, 0.0, v_t),
            (stop, PATH_X_M, y1, 0.0, 0.0),
        )
        paths.append(TargetPath("walker", s.kind, tgt.length_m, tgt.width_m, legs2, 0.0))
    elif s.name == "TN-BEHIND":
        # steps off the kerb 1.0 s after the VUT's rear has passed the path
        y0 = KERB_STOP_Y_M
        go = t_c + (VUT_LENGTH_M + tgt.width_m) / v_car + 1.0
        legs3 = ((0.0, PATH_X_M, y0, 0.0, 0.0), (go, PATH_X_M, y0, 0.0, v_t))
        paths.append(TargetPath("walker", s.kind, tgt.length_m, tgt.width_m, legs3, 0.0))
    else:  # TN-PHONES: four people on the sidewalk, two standing, two strolling
        for k, (dx, dy, vx) in enumerate(
            ((-6.0, 0.0, 0.0), (2.0, -0.8, 0.0), (-12.0, 0.5, v_t), (8.0, -0.4, -v_t))
        ):
            legs4 = ((0.0, PATH_X_M + dx, SIDEWALK_Y_M + dy, vx, 0.0),)
            heading = 270.0 if vx < 0 else 90.0
            paths.append(
                TargetPath(f"phone-{k}", s.kind, tgt.length_m, tgt.width_m, legs4, heading)
            )
    return Plan(cell, start_x, v_car, t_c, tuple(paths), ())
