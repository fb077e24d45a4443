"""Every simulator's coordinates to and from the rfsas frame, in one place.

The rfsas frame: metres east (``x``) and north (``y``) of a site origin,
headings as compass degrees (clockwise from north), positions at the centre
of an entity's box. Simulators differ in three ways, each captured by a
:class:`SimFrame`:

- where a reported position sits on the entity: SUMO reports a vehicle's
  *front bumper* centre (a person's centre); the others the box centre;
- which way the second axis points: highway-env's and CARLA's ``y`` point
  south (screen and Unreal conventions), the rest north;
- how headings are measured: SUMO's ``angle`` is already a compass angle in
  degrees; highway-env's heading is radians from east towards its ``y``
  (south), so compass = 90° + heading; MetaDrive's ``heading_theta`` and ROS's
  REP-103 yaw are radians counter-clockwise from east, so compass = 90° −
  heading; CARLA's yaw is degrees from its ``x`` towards its ``y`` (south),
  so compass = 90° + yaw.

All functions take numbers or numpy arrays (broadcast together).

Example::

    from rfsas_hw.bridges.coords import FRAMES
    east, north, compass = FRAMES["sumo"].to_rfsas(x, y, angle, length_m=4.5,
                                                   origin=(100.0, 100.0))
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import ConfigError

Array = npt.NDArray[np.float64]
Number = float | npt.ArrayLike

__all__ = ["FRAMES", "SimFrame", "frame"]


@dataclass(frozen=True)
class SimFrame:
    """One simulator's coordinate convention (see the module docstring)."""

    name: str
    """Simulator name (``sumo``, ``highway-env``, ``metadrive``, ``carla``, ``ros-enu``)."""
    y_north: bool
    """True when the simulator's ``y`` axis points north, False when it points south."""
    heading_offset_deg: float
    """Compass heading of the simulator's heading zero, degrees."""
    heading_sign: Literal[1, -1]
    """+1 when the simulator's heading turns clockwise (on the map), -1 counter-clockwise."""
    heading_unit: Literal["deg", "rad"]
    """Unit of the simulator's heading."""
    vehicle_reference: Literal["centre", "front-bumper"]
    """Where the simulator's reported vehicle position sits."""

    def heading_to_compass(self, heading: Number) -> Array:
        """Compass degrees of a simulator heading, in [0, 360)."""
        h = np.asarray(heading, np.float64)
        deg = np.degrees(h) if self.heading_unit == "rad" else h
        return np.asarray(np.mod(self.heading_offset_deg + self.heading_sign * deg, 360.0))

    def compass_to_heading(self, compass_deg: Number) -> Array:
        """The simulator's heading for a compass heading (radians in (-π, π], degrees as the
        simulator reports them: SUMO in [0, 360), CARLA in (-180, 180])."""
        c = np.asarray(compass_deg, np.float64)
        deg = self.heading_sign * (c - self.heading_offset_deg)
        if self.name == "sumo":
            return np.asarray(np.mod(deg, 360.0))
        wrapped = -np.mod(-deg + 180.0, 360.0) + 180.0  # (-180, 180]
        return np.asarray(np.radians(wrapped) if self.heading_unit == "rad" else wrapped)

    def to_rfsas(
        self,
        x: Number,
        y: Number,
        heading: Number,
        *,
        length_m: Number = 0.0,
        reference: Literal["centre", "front-bumper"] | None = None,
        origin: tuple[float, float] = (0.0, 0.0),
    ) -> tuple[Array, Array, Array]:
        """East and north of the box centre (metres) and the compass heading (degrees).

        Args:
            x, y: the simulator's position.
            heading: the simulator's heading.
            length_m: the entity's length, metres (moves a front-bumper position back
                by half of it along the heading).
            reference: where ``(x, y)`` sits on the entity (default: the frame's
                ``vehicle_reference``; pass ``"centre"`` for SUMO persons).
            origin: the site origin in the simulator's coordinates.
        """
        compass = self.heading_to_compass(heading)
        east = np.asarray(x, np.float64) - origin[0]
        north_sim = np.asarray(y, np.float64) - origin[1]
        north = north_sim if self.y_north else -north_sim
        if (reference or self.vehicle_reference) == "front-bumper":
            a = np.radians(compass)
            half = np.asarray(length_m, np.float64) / 2.0
            east = east - half * np.sin(a)
            north = north - half * np.cos(a)
        return np.asarray(east), np.asarray(north), compass

    def from_rfsas(
        self,
        east_m: Number,
        north_m: Number,
        compass_deg: Number,
        *,
        length_m: Number = 0.0,
        reference: Literal["centre", "front-bumper"] | None = None,
        origin: tuple[float, float] = (0.0, 0.0),
    ) -> tuple[Array, Array, Array]:
        """The simulator's ``(x, y, heading)`` of a box centre and compass heading.

        The inverse of :meth:`to_rfsas` with the same ``length_m``, ``reference``
        and ``origin``.
        """
        c = np.asarray(compass_deg, np.float64)
        east = np.asarray(east_m, np.float64)
        north = np.asarray(north_m, np.float64)
        if (reference or self.vehicle_reference) == "front-bumper":
            a = np.radians(c)
            half = np.asarray(length_m, np.float64) / 2.0
            east = east + half * np.sin(a)
            north = north + half * np.cos(a)
        y_sim = north if self.y_north else -north
        return (
            np.asarray(east + origin[0]),
            np.asarray(y_sim + origin[1]),
            self.compass_to_heading(c),
        )


FRAMES: dict[str, SimFrame] = {
    "sumo": SimFrame("sumo", True, 0.0, 1, "deg", "front-bumper"),
    "highway-env": SimFrame("highway-env", False, 90.0, 1, "rad", "centre"),
    "metadrive": SimFrame("metadrive", True, 90.0, -1, "rad", "centre"),
    "carla": SimFrame("carla", False, 90.0, 1, "deg", "centre"),
    "ros-enu": SimFrame("ros-enu", True, 90.0, -1, "rad", "centre"),
}
"""The conventions of every simulator the bridges know, by name."""


def frame(name: str) -> SimFrame:
    """The convention named ``name``.

    Raises:
        ConfigError: unknown simulator.
    """
    try:
        return FRAMES[name]
    except KeyError:
        known = ", ".join(sorted(FRAMES))
        raise ConfigError(f"unknown simulator frame {name!r} (known: {known})") from None
