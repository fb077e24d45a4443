"""The site map the dashboard draws under everything: buildings, roads, areas.

Two sources, told apart by the file suffix:

- a scenario (``.yaml``/``.yml``, :mod:`rfsas_hw.twin.scenario`): its
  buildings as footprints and the two crossing roads of its intersection
  (``road_half_width_m`` either side of the axes, out to ``road_length_m``);
- a GeoJSON file (``.geojson``/``.json``, RFC 7946, WGS-84): every Polygon,
  MultiPolygon, LineString and MultiLineString feature, converted to local
  metres through the site origin; ``properties.kind`` (``building``,
  ``road``…) or ``properties.name`` label it. Points are ignored.

Only geometry and names are taken; nothing else of a scenario (emitter MACs,
capture-card addresses) reaches the page.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rfsas_hw.errors import ConfigError
from rfsas_hw.geo import SiteOrigin

ROAD_LENGTH_M = 200.0
"""How far a scenario's roads are drawn from the centre, metres."""

__all__ = ["MapFeature", "load_site_map"]


@dataclass(frozen=True, slots=True)
class MapFeature:
    """One drawn shape in local metres."""

    kind: str
    """``building``, ``road``, ``area`` or ``line`` (or a GeoJSON ``kind`` property)."""
    points: tuple[tuple[float, float], ...]
    """Vertices (east m, north m); a closed shape does not repeat its first vertex."""
    closed: bool
    """A polygon (True) or a polyline."""
    name: str = ""

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready mapping."""
        return {
            "kind": self.kind,
            "name": self.name,
            "closed": self.closed,
            "points": [[round(x, 3), round(y, 3)] for x, y in self.points],
        }


def _box(x0: float, x1: float, y0: float, y1: float) -> tuple[tuple[float, float], ...]:
    return ((x0, y0), (x1, y0), (x1, y1), (x0, y1))


def _from_scenario(path: Path) -> list[MapFeature]:
    from rfsas_hw.twin.scenario import load_scenario

    inter = load_scenario(path).spec.intersection
    h, far = inter.road_half_width_m, ROAD_LENGTH_M
    out = [
        MapFeature("road", _box(-far, far, -h, h), True, "east-west"),
        MapFeature("road", _box(-h, h, -far, far), True, "north-south"),
    ]
    for b in inter.buildings:
        box = _box(b.x_min_m, b.x_max_m, b.y_min_m, b.y_max_m)
        out.append(MapFeature("building", box, True, b.name))
    return out


def _ring(coords: Any, origin: SiteOrigin, where: str) -> tuple[tuple[float, float], ...]:
    try:
        arr = np.asarray(coords, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"{where}: coordinates are not numbers") from err
    if arr.ndim != 2 or arr.shape[1] < 2 or len(arr) < 2:
        raise ConfigError(f"{where}: expected a list of [lon, lat] positions")
    if (np.abs(arr[:, 0]) > 180).any() or (np.abs(arr[:, 1]) > 90).any():
        raise ConfigError(f"{where}: a position is not [longitude, latitude] in degrees")
    east, north, _ = origin.to_local(arr[:, 1], arr[:, 0])
    pts = tuple((float(e), float(n)) for e, n in zip(east, north, strict=True))
    return pts[:-1] if len(pts) > 2 and pts[0] == pts[-1] else pts


def _from_geojson(path: Path, origin: SiteOrigin | None) -> list[MapFeature]:
    if origin is None:
        raise ConfigError(f"{path}: a GeoJSON map needs the site origin (site.origin or --origin)")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except OSError as err:
        raise ConfigError(f"{path}: cannot read: {err.strerror or err}") from err
    except json.JSONDecodeError as err:
        raise ConfigError(f"{path}: not JSON: {err.msg} at line {err.lineno}") from err
    features: Sequence[Any]
    if isinstance(doc, dict) and doc.get("type") == "FeatureCollection":
        features = doc.get("features") or []
    elif isinstance(doc, dict) and doc.get("type") == "Feature":
        features = [doc]
    else:
        raise ConfigError(f"{path}: expected a GeoJSON FeatureCollection or Feature")
    out: list[MapFeature] = []
    for i, feat in enumerate(features):
        where = f"{path}: feature {i}"
        if not isinstance(feat, dict) or not isinstance(feat.get("geometry"), dict):
            raise ConfigError(f"{where}: not a Feature with a geometry")
        props = feat.get("properties") or {}
        name = str(props.get("name", "")) if isinstance(props, dict) else ""
        kind_prop = props.get("kind") if isinstance(props, dict) else None
        geom = feat["geometry"]
        gtype, coords = geom.get("type"), geom.get("coordinates")
        if gtype in ("Polygon", "MultiPolygon"):
            polys = [coords] if gtype == "Polygon" else coords
            for poly in polys or []:
                if poly:
                    ring = _ring(poly[0], origin, where)
                    out.append(MapFeature(str(kind_prop or "area"), ring, True, name))
        elif gtype in ("LineString", "MultiLineString"):
            lines = [coords] if gtype == "LineString" else coords
            for line in lines or []:
                points = _ring(line, origin, where)
                out.append(MapFeature(str(kind_prop or "line"), points, False, name))
    return out


def load_site_map(path: str | Path, origin: SiteOrigin | None) -> list[MapFeature]:
    """Read the site map at ``path`` (a scenario or a GeoJSON file, by suffix).

    Raises:
        ConfigError: an unknown suffix, an unreadable or malformed file, or a
            GeoJSON map without an origin (the feature is named).
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix in (".yaml", ".yml"):
        return _from_scenario(p)
    if suffix in (".geojson", ".json"):
        return _from_geojson(p, origin)
    raise ConfigError(f"{p}: a site map is a scenario (.yaml) or a GeoJSON file (.geojson)")
