"""Rigid motions and swaps: what the geometry says must not change, does not."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from rfsas_hw.backend.collision import collision_probability
from rfsas_hw.backend.triangulation import triangulate

coord = st.floats(-50, 50)
angle = st.floats(0, 360)
positive = st.floats(0.05, 4.0)
size = st.tuples(st.floats(0.0, 5.0), st.floats(0.0, 5.0))


def rotation(deg: float) -> np.ndarray:
    """Rotates east/north vectors clockwise by ``deg`` (a compass rotation)."""
    a = math.radians(-deg)
    return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


def cov_of(sx: float, sy: float, rho: float) -> np.ndarray:
    return np.array([[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]])


@settings(max_examples=60, deadline=None)
@given(
    coord, coord, angle, positive, positive, st.floats(-0.9, 0.9), size,
    coord, coord, angle, positive, positive, st.floats(-0.9, 0.9), size,
    angle, coord, coord,
)  # fmt: skip
def test_collision_probability_is_invariant_under_swaps_and_rigid_motions(
    xv: float, yv: float, hv: float, sxv: float, syv: float, rv: float, bv: tuple[float, float],
    xt: float, yt: float, ht: float, sxt: float, syt: float, rt: float, bt: tuple[float, float],
    turn: float, dx: float, dy: float,
) -> None:  # fmt: skip
    # keep the pair close enough for the probability not to be 0 to round-off
    xt, yt = xv + (xt % 8) - 4, yv + (yt % 8) - 4
    cv, ct = cov_of(sxv, syv, rv), cov_of(sxt, syt, rt)
    p = collision_probability([xv, yv], hv, cv, bv, [xt, yt], ht, ct, bt)
    assert 0.0 <= p <= 1.0
    # overlap is symmetric: swapping the two boxes changes nothing
    swapped = collision_probability([xt, yt], ht, ct, bt, [xv, yv], hv, cv, bv)
    assert abs(p - swapped) < 1e-9
    # turn the whole scene by `turn` degrees clockwise about the origin and shift it
    R, shift = rotation(turn), np.array([dx, dy])
    moved = collision_probability(
        R @ [xv, yv] + shift, hv + turn, R @ cv @ R.T, bv,
        R @ [xt, yt] + shift, ht + turn, R @ ct @ R.T, bt,
    )  # fmt: skip
    assert abs(p - moved) < 1e-9


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(coord, coord), min_size=2, max_size=5),
    st.tuples(coord, coord),
    st.floats(0.3, 3.0),
    angle,
    coord,
    coord,
)
def test_triangulation_moves_with_the_scene(
    stations: list[tuple[float, float]],
    target: tuple[float, float],
    sigma: float,
    turn: float,
    dx: float,
    dy: float,
) -> None:
    S = np.array(stations)
    T = np.array(target)
    d = T - S
    az = 90.0 - np.degrees(np.arctan2(d[:, 1], d[:, 0]))  # compass azimuths, unwrapped
    sig = np.full(len(S), sigma)
    fix = triangulate(S, az + 0.3, sig)
    R, shift = rotation(turn), np.array([dx, dy])
    moved = triangulate(S @ R.T + shift, az + 0.3 + turn, sig)
    # (a status may flip only for a geometry sitting exactly on an acceptance limit)
    if fix.ok and moved.ok:
        np.testing.assert_allclose(moved.position, R @ fix.position + shift, atol=1e-5)
        np.testing.assert_allclose(moved.covariance, R @ fix.covariance @ R.T, rtol=1e-5, atol=1e-9)
