"""The site a backend watches: its origin on the globe, its sensors, its map.

The ``site:`` section of the backend settings (YAML)::

    site:
      origin: {lat_deg: 52.20530, lon_deg: 0.12180, height_m: 12.0}
      map: examples/crossing.yaml        # buildings/roads: a scenario or a GeoJSON file
      tiles: https://tile.example.org/{z}/{x}/{y}.png   # optional, for the dashboard
      sensors:
        rsu-nw: {x_m: -9.0, y_m: 9.0, heading_deg: 140.0, fov_deg: 60}
        rsu-se: {lat_deg: 52.205210, lon_deg: 0.121950, heading_deg: 320.0}

A sensor pose is given either in local metres (``x_m``, ``y_m``) or on the
globe (``lat_deg``, ``lon_deg``; needs ``origin``), always with the boresight
``heading_deg`` (compass). Geodetic poses are converted once, on loading,
through :class:`~rfsas_hw.geo.SiteOrigin`; everything downstream works in
local metres. The poses in signed messages stay authoritative: the site's
sensors give the dashboard a sensor's field of view, and a position for
sensors not heard yet.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rfsas_hw.errors import ConfigError
from rfsas_hw.geo import SiteOrigin, site_origin_from_mapping
from rfsas_hw.records import Pose

DEFAULT_FOV_DEG = 90.0
"""Field of view drawn for a sensor whose width the site does not give, degrees."""

__all__ = [
    "DEFAULT_FOV_DEG",
    "SiteConfig",
    "SiteSensor",
    "parse_origin",
    "pose_from_mapping",
    "site_from_mapping",
]


@dataclass(frozen=True, slots=True)
class SiteSensor:
    """A sensor the site declares: where it stands and how wide it looks."""

    id: str
    """Sensor id, as in its messages."""
    pose: Pose
    """Position (local metres) and boresight (compass degrees)."""
    fov_deg: float = DEFAULT_FOV_DEG
    """Full width of the field of view, degrees, in (0, 360]."""


@dataclass(frozen=True, slots=True)
class SiteConfig:
    """Origin, declared sensors, map file and tile URL of a site (all optional)."""

    origin: SiteOrigin | None = None
    """What local (0, 0, 0) is on WGS-84 (None: outputs stay in local metres)."""
    sensors: tuple[SiteSensor, ...] = ()
    """Declared sensors."""
    map: Path | None = None
    """Buildings and roads: a scenario YAML or a GeoJSON file."""
    tiles: str | None = None
    """Map tile URL template with ``{z}``, ``{x}``, ``{y}`` for the dashboard."""

    def sensor(self, sensor_id: str) -> SiteSensor | None:
        """The declared sensor ``sensor_id``, or None."""
        return next((s for s in self.sensors if s.id == sensor_id), None)


_TILES_RE = re.compile(r"https?://[A-Za-z0-9.-]+(:[0-9]{1,5})?(/[A-Za-z0-9._~:/?&=%{}-]*)?")
"""A tile URL template: a plain host (and port), then a path of URL characters."""


def _number(data: Mapping[str, Any], key: str, where: str) -> float:
    raw = data[key]
    if isinstance(raw, bool) or not isinstance(raw, int | float) or not math.isfinite(raw):
        raise ConfigError(f"{where}.{key}: expected a finite number, got {raw!r}")
    return float(raw)


def pose_from_mapping(data: Any, origin: SiteOrigin | None, where: str) -> Pose:
    """A pose from ``{x_m, y_m, heading_deg}`` or ``{lat_deg, lon_deg, heading_deg}``.

    Args:
        data: the mapping (other keys are the caller's business and ignored here).
        origin: the site origin geodetic poses are converted against.
        where: names the place for errors (``"site.yaml: site.sensors.rsu-1"``).

    Raises:
        ConfigError: both or neither form, a missing or non-numeric value, or a
            geodetic pose without an origin.
    """
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected a mapping with a pose")
    local = "x_m" in data or "y_m" in data
    geodetic = "lat_deg" in data or "lon_deg" in data
    if local == geodetic:
        raise ConfigError(
            f"{where}: give the position as x_m, y_m (local metres) "
            "or as lat_deg, lon_deg (WGS-84), not both or neither"
        )
    if "heading_deg" not in data:
        raise ConfigError(f"{where}: missing key heading_deg")
    heading = _number(data, "heading_deg", where) % 360.0
    keys = ("x_m", "y_m") if local else ("lat_deg", "lon_deg")
    for key in keys:
        if key not in data:
            raise ConfigError(f"{where}: missing key {key}")
    a, b = (_number(data, key, where) for key in keys)
    if local:
        return Pose(a, b, heading)
    if origin is None:
        raise ConfigError(f"{where}: a pose in lat_deg/lon_deg needs the site origin")
    if abs(a) > 90 or abs(b) > 180:
        raise ConfigError(f"{where}: ({a}, {b}) is not a latitude/longitude in degrees")
    east, north, _ = origin.to_local(a, b)
    return Pose(float(east), float(north), heading)


def parse_origin(text: str) -> SiteOrigin:
    """``"LAT,LON"`` or ``"LAT,LON,HEIGHT"`` (degrees, degrees, metres) to a site origin.

    Raises:
        ConfigError: not two or three numbers, or out of range.
    """
    parts = text.split(",")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) not in (2, 3):
        raise ConfigError(f"origin {text!r}: expected LAT_DEG,LON_DEG[,HEIGHT_M]")
    try:
        return SiteOrigin(*values)
    except ConfigError as err:
        raise ConfigError(f"origin {text!r}: {err}") from err


SENSOR_KEYS = {"x_m", "y_m", "lat_deg", "lon_deg", "heading_deg", "fov_deg"}


def site_from_mapping(data: Any, where: str, base_dir: Path | None = None) -> SiteConfig:
    """Build a :class:`SiteConfig` from the ``site:`` mapping (see the module docstring).

    Args:
        data: the mapping (None: an empty site).
        where: names the place for errors (``"backend.yaml: site"``).
        base_dir: a relative ``map`` path is taken relative to this directory.

    Raises:
        ConfigError: an unknown key, a bad origin, pose, field of view or tile URL.
    """
    if data is None:
        return SiteConfig()
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected a mapping (origin, sensors, map, tiles)")
    unknown = set(data) - {"origin", "sensors", "map", "tiles"}
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(sorted(map(str, unknown)))}")
    origin = None
    if data.get("origin") is not None:
        origin = site_origin_from_mapping(data["origin"], f"{where}.origin")
    sensors = []
    raw_sensors = data.get("sensors") or {}
    if not isinstance(raw_sensors, Mapping):
        raise ConfigError(f"{where}.sensors: expected a mapping of sensor id to pose")
    for sid, spec in raw_sensors.items():
        at = f"{where}.sensors.{sid}"
        if isinstance(spec, Mapping):
            extra = set(spec) - SENSOR_KEYS
            if extra:
                raise ConfigError(f"{at}: unknown key(s) {', '.join(sorted(map(str, extra)))}")
        pose = pose_from_mapping(spec, origin, at)
        fov = _number(spec, "fov_deg", at) if "fov_deg" in spec else DEFAULT_FOV_DEG
        if not 0 < fov <= 360:
            raise ConfigError(f"{at}.fov_deg: must be in (0, 360], got {fov:g}")
        sensors.append(SiteSensor(str(sid), pose, fov))
    map_path = None
    if data.get("map") is not None:
        if not isinstance(data["map"], str):
            raise ConfigError(f"{where}.map: expected a file name")
        map_path = Path(data["map"])
        if base_dir is not None and not map_path.is_absolute():
            map_path = base_dir / map_path
    tiles = data.get("tiles")
    if tiles is not None:
        if not isinstance(tiles, str) or not all(f"{{{k}}}" in tiles for k in "zxy"):
            raise ConfigError(f"{where}.tiles: expected a URL template with {{z}}, {{x}}, {{y}}")
        if not tiles.startswith(("http://", "https://")):
            raise ConfigError(f"{where}.tiles: expected an http(s) URL, got {tiles!r}")
        if not _TILES_RE.fullmatch(tiles):
            # the host goes into the dashboard's Content-Security-Policy header: a ';'
            # or a space there would add directives of its own
            raise ConfigError(
                f"{where}.tiles: {tiles!r} has characters a tile URL does not need "
                "(only letters, digits and - . _ ~ : / ? & = % { } are taken)"
            )
    return SiteConfig(origin=origin, sensors=tuple(sensors), map=map_path, tiles=tiles)
