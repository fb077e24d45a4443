"""Each simulator's convention to and from the rfsas frame, checked against the simulator's own
direction vectors where its package is installed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rfsas_hw.bridges.coords import FRAMES, frame
from rfsas_hw.errors import ConfigError


def _bearing(dx: float, dy: float) -> float:
    """Compass bearing of an east/north displacement."""
    return math.degrees(math.atan2(dx, dy)) % 360.0


def _check_forward(name: str, x: float, y: float, heading: float, fx: float, fy: float) -> None:
    """Moving along the simulator's own forward vector goes the converted compass way."""
    f = FRAMES[name]
    e0, n0, c0 = f.to_rfsas(x, y, heading, reference="centre", origin=(3.0, -4.0))
    e1, n1, _ = f.to_rfsas(x + fx, y + fy, heading, reference="centre", origin=(3.0, -4.0))
    got = _bearing(float(e1 - e0), float(n1 - n0))
    assert math.isclose(
        (got - float(c0) + 180) % 360 - 180, 0.0, abs_tol=1e-4
    )  # CARLA vectors are float32


@pytest.mark.parametrize("heading", [-2.5, -1.0, 0.0, 0.3, 1.5707963, 3.0])
def test_highway_env_heading_and_downward_y(heading: float) -> None:
    kin = pytest.importorskip(
        "highway_env.vehicle.kinematics",
        reason="needs the highway extra: pip install 'rfsas-hw[highway]'",
    )
    v = kin.Vehicle(None, [10.0, 5.0], heading=heading, speed=5.0)
    _check_forward("highway-env", 10.0, 5.0, heading, *v.direction)
    # the facts: heading 0 is east, +π/2 points down the screen (south)
    assert float(FRAMES["highway-env"].heading_to_compass(0.0)) == pytest.approx(90.0)
    assert float(FRAMES["highway-env"].heading_to_compass(math.pi / 2)) == pytest.approx(180.0)


@pytest.mark.parametrize("yaw", [-170.0, -90.0, 0.0, 30.0, 90.0, 179.0])
def test_carla_left_handed_yaw(yaw: float) -> None:
    carla = pytest.importorskip(
        "carla", reason="needs the carla extra: pip install 'rfsas-hw[carla]'"
    )
    fwd = carla.Rotation(pitch=0.0, yaw=yaw, roll=0.0).get_forward_vector()
    _check_forward("carla", 1.0, 2.0, yaw, fwd.x, fwd.y)
    assert float(FRAMES["carla"].heading_to_compass(90.0)) == pytest.approx(180.0)


@pytest.mark.parametrize("theta", [-3.0, -1.0, 0.0, 0.7, math.pi / 2])
def test_metadrive_heading_theta(theta: float) -> None:
    # MetaDrive's heading_theta is atan2 of its heading vector in a y-north frame
    _check_forward("metadrive", 0.0, 0.0, theta, math.cos(theta), math.sin(theta))
    assert float(FRAMES["metadrive"].heading_to_compass(math.pi / 2)) == pytest.approx(0.0)


@pytest.mark.parametrize("yaw", [-3.0, 0.0, 1.0, math.pi / 2])
def test_ros_enu_yaw(yaw: float) -> None:
    _check_forward("ros-enu", 5.0, 5.0, yaw, math.cos(yaw), math.sin(yaw))
    assert float(FRAMES["ros-enu"].heading_to_compass(0.0)) == pytest.approx(90.0)


def test_sumo_front_bumper_to_centre_and_back() -> None:
    f = FRAMES["sumo"]
    # a car heading east (angle 90) whose front bumper is at (110, 100), origin (100, 100)
    e, n, c = f.to_rfsas(110.0, 100.0, 90.0, length_m=5.0, origin=(100.0, 100.0))
    assert (float(e), float(n), float(c)) == pytest.approx((7.5, 0.0, 90.0))
    x, y, a = f.from_rfsas(e, n, c, length_m=5.0, origin=(100.0, 100.0))
    assert (float(x), float(y), float(a)) == pytest.approx((110.0, 100.0, 90.0))
    # persons are reported at their centre
    e, n, _ = f.to_rfsas(110.0, 100.0, 90.0, length_m=0.5, reference="centre", origin=(100, 100))
    assert (float(e), float(n)) == pytest.approx((10.0, 0.0))


@pytest.mark.parametrize("name", sorted(FRAMES))
def test_round_trip_every_frame(name: str) -> None:
    f = frame(name)
    rng = np.random.default_rng(5)
    x, y = rng.uniform(-200, 200, 50), rng.uniform(-200, 200, 50)
    h = f.compass_to_heading(rng.uniform(0, 360, 50))
    length = rng.uniform(0.3, 12.0, 50)
    e, n, c = f.to_rfsas(x, y, h, length_m=length, origin=(12.0, -7.0))
    x2, y2, h2 = f.from_rfsas(e, n, c, length_m=length, origin=(12.0, -7.0))
    np.testing.assert_allclose(x2, x, atol=1e-9)
    np.testing.assert_allclose(y2, y, atol=1e-9)
    np.testing.assert_allclose(h2, h, atol=1e-9)


def test_unknown_frame() -> None:
    with pytest.raises(ConfigError, match="unknown simulator frame 'gazebo'"):
        frame("gazebo")
