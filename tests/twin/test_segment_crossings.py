"""The slab test of segments against buildings: its short path for segments with no
component along an axis gives exactly what the full substitution gives."""

from __future__ import annotations

import numpy as np
import pytest

from rfsas_hw.twin.rfworld import blockage_db, nearest_first, segment_crossings


def _reference(p0: np.ndarray, p1: np.ndarray, rects: np.ndarray) -> np.ndarray:
    """Liang–Barsky with the parallel substitution applied to every segment."""
    d = (p1 - p0)[:, None, :]
    o = p0[:, None, :]
    lo = rects[None, :, [0, 2]]
    hi = rects[None, :, [1, 3]]
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - o) / d
        t2 = (hi - o) / d
    parallel = d == 0
    inside = (o > lo) & (o < hi)
    t_near = np.where(parallel, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
    t_far = np.where(parallel, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
    enter = np.maximum(np.max(t_near, axis=-1), 0.0)
    leave = np.minimum(np.min(t_far, axis=-1), 1.0)
    return np.asarray(leave - enter > 1e-9, dtype=bool)


def test_crossings_equal_the_full_substitution_for_every_kind_of_segment() -> None:
    rng = np.random.default_rng(12)
    rects = np.array(
        [
            [8.0, 60.0, 8.0, 60.0, 20.0],
            [-60.0, -8.0, 8.0, 60.0, 12.5],
            [-60.0, -8.0, -60.0, -8.0, 20.0],
            [8.0, 60.0, -60.0, -8.0, 7.25],
        ]
    )
    crossed = parallel_seen = 0
    for trial in range(3000):
        n = int(rng.integers(1, 16))
        p0 = rng.uniform(-70.0, 70.0, (n, 2))
        p1 = rng.uniform(-70.0, 70.0, (n, 2))
        kind = trial % 5
        if kind == 1:
            p1[:, 0] = p0[:, 0]  # along the y axis
        elif kind == 2:
            p0, p1 = np.round(p0 / 8.0) * 8.0, np.round(p1 / 8.0) * 8.0  # edges and corners
        elif kind == 3:
            p1[: n // 2] = p0[: n // 2]  # zero length
        elif kind == 4:
            p0[0, 1] = np.nan
        want = _reference(p0, p1, rects)
        got = segment_crossings(p0, p1, rects)
        assert got.dtype == want.dtype and got.shape == want.shape
        np.testing.assert_array_equal(got, want)
        loss, hit = blockage_db(p0, p1, rects)
        # a sum of the crossed buildings' losses, in another order than the product's
        np.testing.assert_allclose(loss, want.astype(np.float64) @ rects[:, 4], rtol=1e-12)
        np.testing.assert_array_equal(hit, want.any(axis=1))
        crossed += int(want.sum())
        parallel_seen += int(((p1 - p0) == 0).any())
    assert crossed > 1000 and parallel_seen > 1000
    # four columns only (no loss) are enough for the crossings
    p0, p1 = rng.uniform(-70.0, 70.0, (9, 2)), rng.uniform(-70.0, 70.0, (9, 2))
    np.testing.assert_array_equal(
        segment_crossings(p0, p1, rects[:, :4]), _reference(p0, p1, rects[:, :4])
    )


def test_buildings_far_from_the_segments_change_nothing() -> None:
    """A district of buildings, segments in one corner of it: the answer is the full
    test's, whether or not a building is near the segments, and NaN ends cross nothing."""
    rng = np.random.default_rng(5)
    corner = rng.uniform(0.0, 1000.0, (400, 2))
    size = rng.uniform(5.0, 40.0, (400, 2))
    rects = np.column_stack(
        [corner[:, 0], corner[:, 0] + size[:, 0], corner[:, 1], corner[:, 1] + size[:, 1]]
    )
    rects = np.column_stack([rects, rng.uniform(5.0, 20.0, 400)])
    crossed = 0
    for _ in range(200):
        n = int(rng.integers(1, 30))
        centre = rng.uniform(0.0, 1000.0, 2)
        p0 = centre + rng.uniform(-60.0, 60.0, (n, 2))
        p1 = centre + rng.uniform(-60.0, 60.0, (n, 2))
        want = _reference(p0, p1, rects)
        np.testing.assert_array_equal(segment_crossings(p0, p1, rects), want)
        crossed += int(want.sum())
    assert crossed > 100
    nan = np.full((3, 2), np.nan)
    assert not segment_crossings(nan, nan, rects).any()
    assert segment_crossings(nan, nan, rects).shape == (3, 400)


def test_a_path_through_two_buildings_loses_both_and_an_edge_loses_nothing() -> None:
    """Hand-made: a path along y = 0 from x = 0 to 10 through two boxes; the same
    path along their top edge (y = 1) only grazes them."""
    rects = np.array([[2.0, 4.0, -1.0, 1.0, 20.0], [6.0, 8.0, -1.0, 1.0, 7.25]])
    p0 = np.array([[0.0, 0.0], [0.0, 1.0], [0.0, 0.0], [5.0, 0.0]])
    p1 = np.array([[10.0, 0.0], [10.0, 1.0], [3.0, 0.5], [5.0, 9.0]])
    loss, hit = blockage_db(p0, p1, rects)
    assert loss.tolist() == [27.25, 0.0, 20.0, 0.0]
    assert hit.tolist() == [True, False, True, False]
    assert segment_crossings(p0, p1, rects).tolist() == [
        [True, True],
        [False, False],
        [True, False],
        [False, False],
    ]


def test_paths_from_a_point_need_only_the_buildings_within_their_length() -> None:
    """Paths from a standing sensor, each group clipped only against the buildings
    nearer to its sensor than its longest path (what the twin does per sensor): the
    same losses as against every building; a building left out of a group's list is
    not looked at."""
    rng = np.random.default_rng(8)
    corner = rng.uniform(0.0, 600.0, (300, 2))
    size = rng.uniform(5.0, 40.0, (300, 2))
    rects = np.column_stack(
        [
            corner[:, 0],
            corner[:, 0] + size[:, 0],
            corner[:, 1],
            corner[:, 1] + size[:, 1],
            rng.choice([6.0, 12.5, 20.0], 300),
        ]
    )
    sensors = rng.uniform(100.0, 500.0, (6, 2))
    p0s, p1s, groups = [], [], []
    for sx, sy in sensors:
        n = int(rng.integers(0, 40))
        reach = rng.uniform(0.0, 150.0, n)
        angle = rng.uniform(0.0, 2 * np.pi, n)
        p0s.append(np.tile([sx, sy], (n, 1)))
        p1s.append(np.column_stack([sx + reach * np.cos(angle), sy + reach * np.sin(angle)]))
        dist, order = nearest_first((sx, sy), rects)
        # the distance to each building is the distance to the nearest point of its box
        i = int(order[-1])
        dx = max(rects[i, 0] - sx, sx - rects[i, 1], 0.0)
        dy = max(rects[i, 2] - sy, sy - rects[i, 3], 0.0)
        assert dist[-1] == pytest.approx(np.hypot(dx, dy))
        assert np.all(np.diff(dist) >= 0.0)
        longest = float(reach.max(initial=0.0))
        within = int(np.searchsorted(dist, longest + 1.0, side="right"))
        groups.append((n, np.sort(order[:within])))
    p0, p1 = np.concatenate(p0s), np.concatenate(p1s)
    loss, hit = blockage_db(p0, p1, rects, groups)
    want = _reference(p0, p1, rects[:, :4])
    np.testing.assert_allclose(loss, want.astype(np.float64) @ rects[:, 4], rtol=1e-12)
    np.testing.assert_array_equal(hit, want.any(axis=1))
    assert hit.sum() > 20
    # with an empty list for every group, nothing is crossed (the lists are obeyed)
    none = [(n, np.zeros(0, np.intp)) for n, _ in groups]
    assert not blockage_db(p0, p1, rects, none)[1].any()
    with pytest.raises(ValueError, match="hold"):
        blockage_db(p0, p1, rects, [*groups[:-1], (groups[-1][0] + 1, None)])
