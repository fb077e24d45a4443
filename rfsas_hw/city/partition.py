"""How a district's work is split: tiles to backends, units to twin workers.

Tiles to backends (:func:`plan_tiles`): the zoom-16 tiles of the bearing
topics partition the district. A junction's units must go to one backend
(a fix needs the bearings of both), so tiles that hold units of one junction
are joined first; the joined groups then go, largest first, to the backend
with the fewest units so far. Every other tile of the district goes to the
backend of the nearest tile with units, so every vehicle in the district has
exactly one backend. The result is a :class:`~rfsas_hw.fleet.tiles.TilePlan`
(one group per backend), checked for overlaps as any plan.

Units to workers (:func:`split_units`): whole junctions, largest first, to the
worker with the fewest units so far; a worker's units are close together
(its snapshot holds only the VRUs near them).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol

import numpy as np

from rfsas_hw.errors import ConfigError
from rfsas_hw.fleet.tiles import TileGroup, TilePlan
from rfsas_hw.link.topics import TopicRouter

SAMPLE_M = 50.0
"""Spacing of the points that find the district's tiles, metres."""

__all__ = ["district_tiles", "plan_tiles", "split_units"]


class Site(Protocol):
    """A unit's place (a :class:`~rfsas_hw.city.placement.UnitSite`)."""

    @property
    def id(self) -> str: ...
    @property
    def x_m(self) -> float: ...
    @property
    def y_m(self) -> float: ...
    @property
    def junction(self) -> str: ...
    @property
    def tile(self) -> str: ...


def district_tiles(
    router: TopicRouter, bounds_m: tuple[float, float, float, float]
) -> dict[str, tuple[float, float]]:
    """Every zoom-16 tile the bounds (x_min, y_min, x_max, y_max, metres) touch, with the
    mean of its sample points (frame metres)."""
    x0, y0, x1, y1 = bounds_m
    xs = np.arange(x0, x1 + SAMPLE_M, SAMPLE_M)
    ys = np.arange(y0, y1 + SAMPLE_M, SAMPLE_M)
    found: dict[str, list[tuple[float, float]]] = {}
    for x in xs.tolist():
        for y in ys.tolist():
            found.setdefault(router.tile_of(min(x, x1), min(y, y1)), []).append((x, y))
    return {
        t: (float(np.mean([p[0] for p in pts])), float(np.mean([p[1] for p in pts])))
        for t, pts in found.items()
    }


def _joined_tiles(units: Sequence[Site]) -> list[tuple[set[str], int]]:
    """Tiles joined by junctions (a junction's units in two tiles join them), each
    group with its unit count."""
    parent: dict[str, str] = {}

    def root(t: str) -> str:
        while parent.setdefault(t, t) != t:
            t = parent[t]
        return t

    by_junction: dict[str, list[str]] = {}
    for u in units:
        by_junction.setdefault(u.junction, []).append(u.tile)
    for joined in by_junction.values():
        for t in joined[1:]:
            parent[root(t)] = root(joined[0])
    groups: dict[str, tuple[set[str], int]] = {}
    for u in units:
        r = root(u.tile)
        tiles, n = groups.get(r, (set(), 0))
        tiles.add(u.tile)
        groups[r] = (tiles, n + 1)
    return sorted(groups.values(), key=lambda g: (-g[1], sorted(g[0])))


def plan_tiles(
    units: Sequence[Site], backend_ids: Sequence[str], tiles: dict[str, tuple[float, float]]
) -> TilePlan:
    """One tile group per backend (see the module docstring).

    Args:
        units: the district's units.
        backend_ids: the backends (one group each).
        tiles: every tile of the district with a point in it (:func:`district_tiles`).

    Raises:
        ConfigError: no units, or no backend.
    """
    if not units or not backend_ids:
        raise ConfigError("a district needs at least one unit and one backend")
    load = dict.fromkeys(backend_ids, 0)
    owned: dict[str, set[str]] = {b: set() for b in backend_ids}
    for group, n in _joined_tiles(units):
        b = min(backend_ids, key=lambda k: (load[k], k))
        owned[b] |= group
        load[b] += n
    with_units = {t: b for b, ts in owned.items() for t in ts}
    centres = {t: tiles.get(t) for t in with_units}
    unit_xy = {u.tile: (u.x_m, u.y_m) for u in units}
    for t, xy in tiles.items():
        if t in with_units:
            continue
        nearest = min(
            with_units,
            key=lambda k: math.dist(xy, centres[k] or unit_xy[k]),
        )
        owned[with_units[nearest]].add(t)
    groups = [
        TileGroup(name=b, tiles=tuple(sorted(owned[b])), members=(b,))
        for b in backend_ids
        if owned[b]
    ]
    return TilePlan(groups, "district tile plan")


def split_units(units: Sequence[Site], n_workers: int) -> list[list[Site]]:
    """Whole junctions to at most ``n_workers`` workers (see the module docstring); no
    empty worker.

    Raises:
        ConfigError: ``n_workers`` < 1.
    """
    if n_workers < 1:
        raise ConfigError(f"twin workers must be at least 1, got {n_workers}")
    by_junction: dict[str, list[Site]] = {}
    for u in units:
        by_junction.setdefault(u.junction, []).append(u)
    # neighbouring junctions together: order by position, then deal out in runs
    order = sorted(
        by_junction.values(),
        key=lambda us: (
            round(float(np.mean([u.x_m for u in us])) / 500.0),
            np.mean([u.y_m for u in us]),
        ),
    )
    parts: list[list[Site]] = [[] for _ in range(min(n_workers, len(order)))]
    share = math.ceil(sum(len(us) for us in order) / max(len(parts), 1))
    k = 0
    for us in order:
        if len(parts[k]) >= share and k < len(parts) - 1:
            k += 1
        parts[k].extend(us)
    return [p for p in parts if p]
