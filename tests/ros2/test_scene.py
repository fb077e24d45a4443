"""Conventions of the scene: REP-103 yaw from compass headings, covariance ellipses."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("rosbags", reason="needs the ros2 extra: pip install 'rfsas-hw[ros2]'")

from rfsas_hw.ros2.scene import compass_yaw, ellipse_points, marker_id


@pytest.mark.parametrize(
    ("heading_deg", "yaw_rad"),
    [(0.0, math.pi / 2), (90.0, 0.0), (180.0, -math.pi / 2), (45.0, math.pi / 4), (359.0, 1.5882)],
)
def test_compass_heading_to_enu_yaw(heading_deg: float, yaw_rad: float) -> None:
    assert compass_yaw(heading_deg) == pytest.approx(yaw_rad, abs=1e-4)
    # the yaw points where the heading does: (east, north) = (sin h, cos h)
    h = math.radians(heading_deg)
    yaw = compass_yaw(heading_deg)
    assert (math.cos(yaw), math.sin(yaw)) == pytest.approx((math.sin(h), math.cos(h)))


@pytest.mark.parametrize(
    "cov", [[[4.0, 1.5], [1.5, 1.0]], [[1.0, 0.0], [0.0, 9.0]], [[2.0, -1.9], [-1.9, 2.0]]]
)
def test_ellipse_points_lie_on_the_n_sigma_contour(cov: list[list[float]]) -> None:
    c = np.array(cov)
    pts = np.array(ellipse_points(10.0, -5.0, c, 2.0)) - [10.0, -5.0]
    q = np.einsum("ni,ij,nj->n", pts, np.linalg.inv(c), pts)
    assert q == pytest.approx(np.full(len(pts), 4.0), rel=1e-9)
    assert pts[0] == pytest.approx(pts[-1])  # closed


def test_marker_id_is_a_stable_non_negative_int32() -> None:
    assert marker_id("ffffffff00000000") == 0x7FFFFFFF
    assert marker_id("0123456789abcdef") == 0x01234567
