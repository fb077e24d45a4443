"""GeoJSON (RFC 7946) of a run: for QGIS, web maps and anything that reads GeoJSON.

One ``FeatureCollection``; every feature's ``properties.kind`` says what it is:

- ``fix``: a ``Point`` with the emitter id, time, status, the sensors behind it,
  the covariance (m²) and the ellipse's axes and orientation;
- ``fix_ellipse``: a ``Polygon``, the fix's error ellipse (``n_sigma`` in its
  properties), exterior ring counter-clockwise as RFC 7946 §3.1.6 asks;
- ``bearing``: a ``LineString`` from the sensor along the measured azimuth;
- ``track``: a ``LineString`` of an emitter's track with ``times`` (ISO 8601
  UTC, one per vertex);
- ``sensor``: a ``Point``, the sensor's last reported position.

Coordinates are ``[longitude, latitude]`` in WGS-84 degrees with 8 decimals
(about a millimetre), so positions round-trip to local metres well within a
centimetre.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from rfsas_hw.exports.scene import Scene
from rfsas_hw.exports.shapes import iso_utc
from rfsas_hw.outpaths import write_text_atomic

DECIMALS = 8
"""Decimals of a coordinate in degrees (1e-8° ≈ 1.1 mm of latitude)."""

__all__ = ["feature", "position", "scene_to_geojson", "write_geojson"]


def position(lat: float, lon: float) -> list[float]:
    """A GeoJSON position ``[longitude, latitude]`` in degrees, :data:`DECIMALS` decimals."""
    return [round(float(lon), DECIMALS), round(float(lat), DECIMALS)]


_pos = position


def _clean(value: Any) -> Any:
    """JSON has no NaN: non-finite floats become null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def feature(geometry: dict[str, Any], properties: dict[str, Any]) -> dict[str, Any]:
    """A GeoJSON ``Feature``; non-finite numbers among ``properties`` become null."""
    return {
        "type": "Feature",
        "geometry": geometry,
        "properties": {k: _clean(v) for k, v in properties.items()},
    }


def scene_to_geojson(scene: Scene) -> dict[str, Any]:
    """The scene as a GeoJSON ``FeatureCollection`` (a JSON-ready mapping)."""
    features: list[dict[str, Any]] = []
    for s in scene.sensors:
        features.append(
            feature(
                {"type": "Point", "coordinates": _pos(s.lat_deg, s.lon_deg)},
                {"kind": "sensor", "sensor_id": s.sensor_id, "time": iso_utc(s.t_ns)},
            )
        )
    for m in scene.fixes:
        f = m.fix
        props: dict[str, Any] = {
            "kind": "fix",
            "emitter": f.emitter,
            "time": iso_utc(f.t_ns),
            "t_ns": f.t_ns,
            "ok": f.ok,
            "status": f.status,
            "sensors": list(f.sensors),
            "x_m": f.x_m,
            "y_m": f.y_m,
            "cov_xx_m2": f.cov_xx_m2,
            "cov_xy_m2": f.cov_xy_m2,
            "cov_yy_m2": f.cov_yy_m2,
            "gdop": f.gdop,
        }
        if m.ellipse is not None:
            props.update(
                n_sigma=m.ellipse.n_sigma,
                semi_major_m=round(m.ellipse.semi_major_m, 3),
                semi_minor_m=round(m.ellipse.semi_minor_m, 3),
                orientation_deg=round(m.ellipse.orientation_deg, 2),
            )
        features.append(
            feature({"type": "Point", "coordinates": _pos(m.lat_deg, m.lon_deg)}, props)
        )
        if m.ring_deg is not None and m.ellipse is not None:
            ring = [_pos(lat, lon) for lat, lon in m.ring_deg]
            features.append(
                feature(
                    {"type": "Polygon", "coordinates": [ring]},
                    {
                        "kind": "fix_ellipse",
                        "emitter": f.emitter,
                        "time": iso_utc(f.t_ns),
                        "n_sigma": m.ellipse.n_sigma,
                    },
                )
            )
    for b in scene.bearings:
        features.append(
            feature(
                {"type": "LineString", "coordinates": [_pos(*b.start_deg), _pos(*b.end_deg)]},
                {
                    "kind": "bearing",
                    "sensor_id": b.bearing.sensor_id,
                    "emitter": b.bearing.emitter,
                    "time": iso_utc(b.bearing.t_ns),
                    "azimuth_deg": b.bearing.azimuth_deg,
                    "sigma_deg": b.bearing.sigma_deg,
                    "length_m": b.length_m,
                },
            )
        )
    for t in scene.tracks:
        features.append(
            feature(
                {
                    "type": "LineString",
                    "coordinates": [
                        _pos(lat, lon) for lat, lon in zip(t.lat_deg, t.lon_deg, strict=True)
                    ],
                },
                {
                    "kind": "track",
                    "emitter": t.emitter,
                    "start": iso_utc(int(t.t_ns[0])),
                    "end": iso_utc(int(t.t_ns[-1])),
                    "times": [iso_utc(int(v)) for v in t.t_ns],
                },
            )
        )
    return {"type": "FeatureCollection", "features": features}


def write_geojson(scene: Scene, path: str | Path) -> Path:
    """Write the scene as GeoJSON to ``path``.

    Raises:
        ConfigError: the file cannot be created.
        OutputError: writing it failed (disk full); the target is unchanged.
    """
    p = Path(path)
    write_text_atomic(p, json.dumps(scene_to_geojson(scene), allow_nan=False))
    return p
