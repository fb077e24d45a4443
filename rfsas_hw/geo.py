"""A site on the globe: local east/north/up metres ↔ WGS-84 geodetic coordinates.

Everything inside rfsas-hw works in local metres east and north of a site
origin (the ``x_m``/``y_m`` of poses, fixes and scenarios). A :class:`SiteOrigin`
anchors that plane on the WGS-84 ellipsoid so that outputs can carry latitude
and longitude. The conversion is the exact geodetic ↔ ECEF ↔ ENU chain of
``pymap3d`` (a small, pure-Python, well-tested library), not a flat-earth
approximation: over a site a few kilometres across the two differ by
centimetres, which is the precision the exports promise.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import pymap3d

from rfsas_hw.errors import ConfigError

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class SiteOrigin:
    """The geodetic point that local (0 m east, 0 m north, 0 m up) stands for."""

    lat_deg: float
    """Latitude, degrees north, WGS-84, in [-90, 90]."""
    lon_deg: float
    """Longitude, degrees east, WGS-84, in [-180, 180]."""
    height_m: float = 0.0
    """Height above the WGS-84 ellipsoid, metres."""

    def __post_init__(self) -> None:
        for name, value, bound in (
            ("lat_deg", self.lat_deg, 90.0),
            ("lon_deg", self.lon_deg, 180.0),
            ("height_m", self.height_m, 100_000.0),
        ):
            if not math.isfinite(value) or abs(value) > bound:
                raise ConfigError(
                    f"site origin: {name} must be a number in ±{bound:g}, got {value!r}"
                )

    def to_geodetic(
        self,
        east_m: npt.ArrayLike,
        north_m: npt.ArrayLike,
        up_m: npt.ArrayLike = 0.0,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Local metres → (latitude °, longitude °, ellipsoid height m); arrays broadcast."""
        e, n, u = np.broadcast_arrays(
            np.asarray(east_m, dtype=np.float64),
            np.asarray(north_m, dtype=np.float64),
            np.asarray(up_m, dtype=np.float64),
        )
        lat, lon, h = pymap3d.enu2geodetic(e, n, u, self.lat_deg, self.lon_deg, self.height_m)
        return (
            np.asarray(lat, dtype=np.float64),
            np.asarray(lon, dtype=np.float64),
            np.asarray(h, dtype=np.float64),
        )

    def to_local(
        self,
        lat_deg: npt.ArrayLike,
        lon_deg: npt.ArrayLike,
        height_m: npt.ArrayLike | None = None,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(Latitude °, longitude °, height m) → local (east m, north m, up m).

        A missing height is taken as the origin's, so a point given by latitude
        and longitude alone lands on the site plane (up ≈ 0 nearby).
        """
        h = self.height_m if height_m is None else height_m
        lat, lon, hh = np.broadcast_arrays(
            np.asarray(lat_deg, dtype=np.float64),
            np.asarray(lon_deg, dtype=np.float64),
            np.asarray(h, dtype=np.float64),
        )
        e, n, u = pymap3d.geodetic2enu(lat, lon, hh, self.lat_deg, self.lon_deg, self.height_m)
        return (
            np.asarray(e, dtype=np.float64),
            np.asarray(n, dtype=np.float64),
            np.asarray(u, dtype=np.float64),
        )


def site_origin_from_mapping(data: Mapping[str, Any], where: str) -> SiteOrigin:
    """Build a :class:`SiteOrigin` from ``{lat_deg, lon_deg, height_m?}``.

    ``where`` names the place for errors (``"site.yaml: origin"``).

    Raises:
        ConfigError: a missing or unknown key, or a value that is not a finite
            number in range.
    """
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected a mapping with lat_deg, lon_deg[, height_m]")
    unknown = set(data) - {"lat_deg", "lon_deg", "height_m"}
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(sorted(map(str, unknown)))}")
    values: dict[str, float] = {}
    for key in ("lat_deg", "lon_deg", "height_m"):
        if key not in data:
            if key == "height_m":
                continue
            raise ConfigError(f"{where}: missing key {key}")
        raw = data[key]
        if isinstance(raw, bool) or not isinstance(raw, int | float):
            raise ConfigError(f"{where}.{key}: expected a number, got {raw!r}")
        values[key] = float(raw)
    try:
        return SiteOrigin(**values)
    except ConfigError as err:
        raise ConfigError(f"{where}: {err}") from err
