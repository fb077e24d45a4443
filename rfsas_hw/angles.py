"""Angle conventions and the one place that converts between them.

Users see compass azimuths: degrees clockwise from north, in [0, 360).
Array-relative angles are degrees clockwise from boresight, in (-180, 180].
Geometry inside the backend uses math angles: radians counter-clockwise from
east, as returned by ``atan2(dy, dx)`` on east/north coordinates.
"""

from __future__ import annotations

from typing import TypeVar

import numpy as np
import numpy.typing as npt

FloatOrArray = TypeVar("FloatOrArray", float, npt.NDArray[np.float64])


def wrap_deg_360(angle_deg: FloatOrArray) -> FloatOrArray:
    """Wrap degrees into [0, 360)."""
    return np.mod(angle_deg, 360.0)  # type: ignore[no-any-return]


def wrap_deg_180(angle_deg: FloatOrArray) -> FloatOrArray:
    """Wrap degrees into (-180, 180]."""
    wrapped = 180.0 - np.mod(180.0 - np.asarray(angle_deg, dtype=np.float64), 360.0)
    return wrapped if isinstance(angle_deg, np.ndarray) else float(wrapped)  # type: ignore[return-value]


def wrap_rad_pi(angle_rad: FloatOrArray) -> FloatOrArray:
    """Wrap radians into (-pi, pi]."""
    wrapped = np.pi - np.mod(np.pi - np.asarray(angle_rad, dtype=np.float64), 2 * np.pi)
    return wrapped if isinstance(angle_rad, np.ndarray) else float(wrapped)  # type: ignore[return-value]


def compass_to_math_rad(azimuth_deg: FloatOrArray) -> FloatOrArray:
    """Compass azimuth (deg clockwise from north) to math angle (rad CCW from east)."""
    return wrap_rad_pi(np.deg2rad(90.0 - np.asarray(azimuth_deg, dtype=np.float64)))  # type: ignore[no-any-return]


def math_rad_to_compass(angle_rad: FloatOrArray) -> FloatOrArray:
    """Math angle (rad CCW from east) to compass azimuth (deg clockwise from north, [0, 360))."""
    out = np.mod(90.0 - np.rad2deg(angle_rad), 360.0)
    return out if isinstance(angle_rad, np.ndarray) else float(out)  # type: ignore[return-value]


def relative_to_compass(relative_deg: FloatOrArray, boresight_deg: float) -> FloatOrArray:
    """Array-relative angle (deg clockwise from boresight) to compass azimuth.

    ``boresight_deg`` is the compass azimuth the array's boresight points to.
    """
    return wrap_deg_360(np.asarray(relative_deg, dtype=np.float64) + boresight_deg)  # type: ignore[return-value]
