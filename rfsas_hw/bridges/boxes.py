"""Oriented boxes of simulator entities: do two overlap, and how far apart are they.

A box is an :class:`~rfsas_hw.bridges.bridge.Entity`'s footprint: a rectangle
``length_m`` long along its compass heading and ``width_m`` wide, centred on
its position (rfsas frame: x east, y north, metres). Two convex polygons
overlap when no edge normal of either separates them (the separating-axis
theorem); when they do not overlap, their distance is the shortest distance
between an edge of one and an edge of the other.

"""

from __future__ import annotations

import math
from collections.abc import Sequence

from rfsas_hw.bridges.bridge import Entity

Point = tuple[float, float]

__all__ = ["box_distance", "corners", "overlap", "reach"]


def corners(e: Entity) -> list[Point]:
    """The four corners of ``e``'s box, counter-clockwise, metres (rfsas frame)."""
    a = math.radians(e.heading_deg)
    ux, uy = math.sin(a), math.cos(a)  # along the heading
    vx, vy = -uy, ux  # to the left of it
    hl, hw = e.length_m / 2, e.width_m / 2
    return [
        (e.x_m + sl * hl * ux + sw * hw * vx, e.y_m + sl * hl * uy + sw * hw * vy)
        for sl, sw in ((1, -1), (1, 1), (-1, 1), (-1, -1))
    ]


def _separated(a: Sequence[Point], b: Sequence[Point]) -> bool:
    """Whether an edge normal of ``a`` separates ``a`` from ``b``."""
    n = len(a)
    for i in range(n):
        (x0, y0), (x1, y1) = a[i], a[(i + 1) % n]
        nx, ny = y1 - y0, x0 - x1
        pa = [nx * x + ny * y for x, y in a]
        pb = [nx * x + ny * y for x, y in b]
        if max(pa) < min(pb) or max(pb) < min(pa):
            return True
    return False


def _polys_overlap(a: Sequence[Point], b: Sequence[Point]) -> bool:
    return not (_separated(a, b) or _separated(b, a))


_ROUNDING_M = 1e-9
"""Slack of the circle test in :func:`overlap`, metres: far above floating-point rounding of
a few metres, far below any distance that matters."""


def reach(a: Entity, b: Entity) -> float:
    """The sum of the boxes' half-diagonals, metres: each box lies within that circle round
    its centre, so boxes whose centres are farther apart than this (plus a rounding slack,
    :data:`_ROUNDING_M`) cannot touch."""
    return (math.hypot(a.length_m, a.width_m) + math.hypot(b.length_m, b.width_m)) / 2 + (
        _ROUNDING_M
    )


def overlap(a: Entity, b: Entity) -> bool:
    """Whether the boxes of ``a`` and ``b`` overlap (touching counts).

    Boxes farther apart than their :func:`reach` are not tested edge by edge.
    """
    if math.hypot(a.x_m - b.x_m, a.y_m - b.y_m) > reach(a, b):
        return False
    return _polys_overlap(corners(a), corners(b))


def _point_segment(p: Point, s0: Point, s1: Point) -> float:
    dx, dy = s1[0] - s0[0], s1[1] - s0[1]
    d2 = dx * dx + dy * dy
    t = 0.0 if d2 == 0 else max(0.0, min(1.0, ((p[0] - s0[0]) * dx + (p[1] - s0[1]) * dy) / d2))
    return math.hypot(p[0] - s0[0] - t * dx, p[1] - s0[1] - t * dy)


def box_distance(a: Entity, b: Entity) -> float:
    """The shortest distance between the boxes of ``a`` and ``b``, metres (0 when they overlap)."""
    pa, pb = corners(a), corners(b)
    if _polys_overlap(pa, pb):
        return 0.0
    best = math.inf
    for poly, other in ((pa, pb), (pb, pa)):
        for p in poly:
            for i in range(len(other)):
                best = min(best, _point_segment(p, other[i], other[(i + 1) % len(other)]))
    return best
