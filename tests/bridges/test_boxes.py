"""Oriented boxes: the circle test that spares the edge-by-edge one changes no answer."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rfsas_hw.bridges.boxes import _polys_overlap, box_distance, corners, overlap, reach
from rfsas_hw.bridges.bridge import Entity
from rfsas_hw.bridges.vru_score import VruScore


def _box(x: float, y: float, h: float, length: float = 4.5, width: float = 1.8) -> Entity:
    return Entity("b", "vehicle", x, y, h, 0.0, length, width)


def test_corner_to_corner_contact_at_the_reach_still_counts() -> None:
    # two boxes on one diagonal line, corners touching: centres exactly 'reach' apart
    a = _box(0.0, 0.0, 0.0, 4.0, 3.0)  # half-diagonal 2.5, corner at (1.5, 2.0)
    b = _box(3.0, 4.0, 0.0, 4.0, 3.0)  # corner at (1.5, 2.0)
    assert math.hypot(3.0, 4.0) == pytest.approx(reach(a, b), abs=1e-8)
    assert overlap(a, b) and box_distance(a, b) == 0.0
    c = _box(3.0 + 1e-6, 4.0 + 1e-6, 0.0, 4.0, 3.0)
    assert not overlap(c, a) and box_distance(a, c) > 0.0


def test_overlap_agrees_with_the_edge_test_everywhere() -> None:
    rng = np.random.default_rng(5)
    ego = _box(0.0, 0.0, 90.0)
    disagree = 0
    for _ in range(3000):
        x, y = rng.uniform(-6.0, 6.0, 2)
        other = _box(float(x), float(y), float(rng.uniform(0, 360)), 1.8, 0.6)
        disagree += overlap(ego, other) != _polys_overlap(corners(ego), corners(other))
    assert disagree == 0


def test_vru_score_skips_only_gaps_that_cannot_be_the_smallest() -> None:
    rng = np.random.default_rng(9)
    score = VruScore()
    smallest: dict[str, float] = {}
    for k in range(300):  # an ego driving past two walkers that wander
        ego = _box(-30.0 + 0.2 * k, 0.0, 90.0)
        vrus = [
            (Entity(f"p{i}", "pedestrian", float(x), float(y), 0.0, 1.0, 0.3, 0.5), "pedestrian")
            for i, (x, y) in enumerate(rng.uniform([-5, 1.2], [5, 6], (2, 2)))
        ]
        score.update("ego", ego, vrus)
        for v, cls in vrus:
            smallest[cls] = min(smallest.get(cls, math.inf), box_distance(ego, v))
    assert score.min_gap_by_class == smallest
    assert score.min_gap_m == min(smallest.values())
