"""Angle conventions and the one place that converts between them.

Users see compass azimuths: degrees clockwise from north, in [0, 360).
Array-relative angles are degrees clockwise from boresight, in (-180, 180].
Geometry inside the backend uses math angles: radians counter-clockwise from
east, as returned by ``atan2(dy, dx)`` on east/north coordinates.

Every function takes a float or a numpy array and returns the same kind
(a float goes through the same numpy operations as an array).
"""

from __future__ import annotations

from typing import Any, overload

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]


def _same_kind(value: Any, result: Any) -> Any:
    return result if isinstance(value, np.ndarray) else float(result)


@overload
def wrap_deg_360(angle_deg: float) -> float: ...
@overload
def wrap_deg_360(angle_deg: Array) -> Array: ...
def wrap_deg_360(angle_deg: float | Array) -> float | Array:
    """Wrap degrees into [0, 360)."""
    out = np.mod(np.asarray(angle_deg, dtype=np.float64), 360.0)
    # np.mod can return exactly 360.0 for tiny negative inputs
    out = np.where(out >= 360.0, 0.0, out)
    return _same_kind(angle_deg, out)  # type: ignore[no-any-return]


@overload
def wrap_deg_180(angle_deg: float) -> float: ...
@overload
def wrap_deg_180(angle_deg: Array) -> Array: ...
def wrap_deg_180(angle_deg: float | Array) -> float | Array:
    """Wrap degrees into (-180, 180]."""
    out = 180.0 - np.mod(180.0 - np.asarray(angle_deg, dtype=np.float64), 360.0)
    return _same_kind(angle_deg, out)  # type: ignore[no-any-return]


@overload
def wrap_rad_pi(angle_rad: float) -> float: ...
@overload
def wrap_rad_pi(angle_rad: Array) -> Array: ...
def wrap_rad_pi(angle_rad: float | Array) -> float | Array:
    """Wrap radians into (-pi, pi]."""
    out = np.pi - np.mod(np.pi - np.asarray(angle_rad, dtype=np.float64), 2 * np.pi)
    return _same_kind(angle_rad, out)  # type: ignore[no-any-return]


@overload
def compass_to_math_rad(azimuth_deg: float) -> float: ...
@overload
def compass_to_math_rad(azimuth_deg: Array) -> Array: ...
def compass_to_math_rad(azimuth_deg: float | Array) -> float | Array:
    """Compass azimuth (deg clockwise from north) to math angle (rad CCW from east, (-pi, pi])."""
    out = np.deg2rad(90.0 - np.asarray(azimuth_deg, dtype=np.float64))
    out = np.pi - np.mod(np.pi - out, 2 * np.pi)
    return _same_kind(azimuth_deg, out)  # type: ignore[no-any-return]


@overload
def math_rad_to_compass(angle_rad: float) -> float: ...
@overload
def math_rad_to_compass(angle_rad: Array) -> Array: ...
def math_rad_to_compass(angle_rad: float | Array) -> float | Array:
    """Math angle (rad CCW from east) to compass azimuth (deg clockwise from north, [0, 360))."""
    out = wrap_deg_360(90.0 - np.rad2deg(np.asarray(angle_rad, dtype=np.float64)))
    return _same_kind(angle_rad, out)  # type: ignore[no-any-return]


@overload
def relative_to_compass(relative_deg: float, boresight_deg: float) -> float: ...
@overload
def relative_to_compass(relative_deg: Array, boresight_deg: float) -> Array: ...
def relative_to_compass(relative_deg: float | Array, boresight_deg: float) -> float | Array:
    """Array-relative angle (deg clockwise from boresight) to compass azimuth.

    ``boresight_deg`` is the compass azimuth the array's boresight points to.
    """
    out = wrap_deg_360(np.asarray(relative_deg, np.float64) + boresight_deg)
    return _same_kind(relative_deg, out)  # type: ignore[no-any-return]
