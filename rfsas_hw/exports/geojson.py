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
centimetre. The file is written as the run log is read (see
:func:`geojson_chunks`).
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from rfsas_hw.exports.scene import BearingMark, FixMark, SceneStream, SensorMark, TrackPath
from rfsas_hw.exports.shapes import iso_utc
from rfsas_hw.exports.spill import Spool
from rfsas_hw.outpaths import write_chunks_atomic

DECIMALS = 8
"""Decimals of a coordinate in degrees (1e-8° ≈ 1.1 mm of latitude)."""

SEPARATOR = ", "
"""Between two features, as ``json.dumps`` writes a list."""

__all__ = ["feature", "geojson_chunks", "position", "write_geojson"]


def position(lat: float, lon: float) -> list[float]:
    """A GeoJSON position ``[longitude, latitude]`` in degrees, :data:`DECIMALS` decimals."""
    return [round(float(lon), DECIMALS), round(float(lat), DECIMALS)]


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


def _sensor_feature(s: SensorMark) -> dict[str, Any]:
    return feature(
        {"type": "Point", "coordinates": position(s.lat_deg, s.lon_deg)},
        {"kind": "sensor", "sensor_id": s.sensor_id, "time": iso_utc(s.t_ns)},
    )


def _fix_features(m: FixMark) -> list[dict[str, Any]]:
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
    features = [feature({"type": "Point", "coordinates": position(m.lat_deg, m.lon_deg)}, props)]
    if m.ring_deg is not None and m.ellipse is not None:
        ring = [position(lat, lon) for lat, lon in m.ring_deg]
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
    return features


def _bearing_feature(b: BearingMark) -> dict[str, Any]:
    return feature(
        {"type": "LineString", "coordinates": [position(*b.start_deg), position(*b.end_deg)]},
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


def _track_feature(t: TrackPath) -> dict[str, Any]:
    coordinates = [position(lat, lon) for lat, lon in zip(t.lat_deg, t.lon_deg, strict=True)]
    return feature(
        {"type": "LineString", "coordinates": coordinates},
        {
            "kind": "track",
            "emitter": t.emitter,
            "start": iso_utc(int(t.t_ns[0])),
            "end": iso_utc(int(t.t_ns[-1])),
            "times": [iso_utc(int(v)) for v in t.t_ns],
        },
    )


def _text(feature: dict[str, Any]) -> bytes:
    return (SEPARATOR + json.dumps(feature, allow_nan=False)).encode()


def geojson_chunks(scene: SceneStream) -> Iterator[bytes]:
    """The scene as a GeoJSON ``FeatureCollection``, in pieces as it is read.

    Sensors come first but are known only at the end, so the fixes and the
    bearings wait in :class:`~rfsas_hw.exports.spill.Spool` files meanwhile;
    the tracks come from the scene's compact track columns.

    Raises:
        OutputError: a temporary file cannot be written.
    """
    with Spool() as fixes, Spool() as bearings:
        for mark in scene.marks():
            if isinstance(mark, FixMark):
                for feature in _fix_features(mark):
                    fixes.write(_text(feature))
            else:
                bearings.write(_text(_bearing_feature(mark)))
        yield b'{"type": "FeatureCollection", "features": ['
        pieces = itertools.chain(
            (_text(_sensor_feature(s)) for s in scene.sensors()),
            fixes.blocks(),
            bearings.blocks(),
            (_text(_track_feature(t)) for t in scene.tracks()),
        )
        first = next(pieces, None)
        if first is not None:
            yield first[len(SEPARATOR) :]  # the list's first feature has no separator
            yield from pieces
        yield b"]}"


def write_geojson(scene: SceneStream, path: str | Path) -> Path:
    """Write the scene as GeoJSON to ``path`` as it is read.

    Raises:
        ConfigError: the file cannot be created.
        OutputError: writing it failed (disk full); the target is unchanged.
    """
    p = Path(path)
    write_chunks_atomic(p, geojson_chunks(scene))
    return p
