"""Shapes in local metres that every map output draws: error ellipses, bearing rays, times.

A fix's 2×2 position covariance (m², east/north) is drawn as the ellipse of
``n_sigma`` standard deviations: semi-axes ``n_sigma·√λ`` along the
eigenvectors. The orientation is the compass direction of the major axis
(degrees clockwise from north, in [0, 180)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime

import numpy as np
import numpy.typing as npt

from rfsas_hw.angles import compass_to_math_rad

Array = npt.NDArray[np.float64]

ELLIPSE_SIGMA = 2.0
"""Standard deviations the drawn error ellipses stand for (as the backend's map PNG)."""
ELLIPSE_POINTS = 48
"""Vertices of a drawn ellipse (the ring closes on the first)."""
BEARING_LENGTH_M = 100.0
"""Length of a drawn bearing ray, metres."""

__all__ = [
    "BEARING_LENGTH_M",
    "ELLIPSE_POINTS",
    "ELLIPSE_SIGMA",
    "Ellipse",
    "bearing_end",
    "ellipse_of",
    "iso_utc",
]


@dataclass(frozen=True, slots=True)
class Ellipse:
    """An error ellipse in local metres."""

    semi_major_m: float
    """Semi-major axis at the ellipse's sigma, metres."""
    semi_minor_m: float
    """Semi-minor axis at the ellipse's sigma, metres."""
    orientation_deg: float
    """Compass direction of the major axis, degrees in [0, 180)."""
    n_sigma: float
    """Standard deviations the axes stand for."""

    def ring(self, x_m: float, y_m: float, n: int = ELLIPSE_POINTS) -> Array:
        """Closed ring of ``n + 1`` points (east, north) around (``x_m``, ``y_m``), metres.

        Counter-clockwise (the exterior-ring order RFC 7946 asks for).
        """
        t = np.linspace(0.0, 2 * math.pi, n + 1)
        t[-1] = 0.0
        a = float(compass_to_math_rad(self.orientation_deg))
        major = np.array([math.cos(a), math.sin(a)])
        minor = np.array([-math.sin(a), math.cos(a)])
        pts: Array = (
            np.array([x_m, y_m])
            + np.outer(np.cos(t) * self.semi_major_m, major)
            + np.outer(np.sin(t) * self.semi_minor_m, minor)
        )
        return pts


def ellipse_of(
    cov_xx_m2: float, cov_xy_m2: float, cov_yy_m2: float, n_sigma: float = ELLIPSE_SIGMA
) -> Ellipse | None:
    """The ``n_sigma`` ellipse of a position covariance, or None if it is not a finite,
    positive semi-definite matrix."""
    cov = np.array([[cov_xx_m2, cov_xy_m2], [cov_xy_m2, cov_yy_m2]], dtype=np.float64)
    if not np.isfinite(cov).all():
        return None
    vals, vecs = np.linalg.eigh(cov)
    if vals[0] < -1e-9 * max(abs(vals[1]), 1.0):
        return None
    vals = np.maximum(vals, 0.0)
    east, north = vecs[0, 1], vecs[1, 1]
    orientation = math.degrees(math.atan2(east, north)) % 180.0
    return Ellipse(
        semi_major_m=float(n_sigma * math.sqrt(vals[1])),
        semi_minor_m=float(n_sigma * math.sqrt(vals[0])),
        orientation_deg=orientation,
        n_sigma=n_sigma,
    )


def bearing_end(
    x_m: float, y_m: float, azimuth_deg: float, length_m: float = BEARING_LENGTH_M
) -> tuple[float, float]:
    """The point ``length_m`` metres from (``x_m``, ``y_m``) along compass ``azimuth_deg``."""
    a = math.radians(azimuth_deg)
    return x_m + length_m * math.sin(a), y_m + length_m * math.cos(a)


def iso_utc(t_ns: int) -> str:
    """UTC nanoseconds as ISO 8601 with milliseconds and a ``Z``."""
    seconds, rest = divmod(int(t_ns), 1_000_000_000)
    stamp = datetime.fromtimestamp(seconds, tz=UTC).strftime("%Y-%m-%dT%H:%M:%S")
    return f"{stamp}.{rest // 1_000_000:03d}Z"
