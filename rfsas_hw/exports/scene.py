"""A run log placed on the globe: what every export format draws, in WGS-84.

:func:`build_scene` turns the local-metre records of a :class:`RunLog` into
geodetic marks through :class:`~rfsas_hw.geo.SiteOrigin` (one vectorised
conversion per kind): fixes with their error-ellipse rings, bearing rays from
the sensor, each emitter's track as a timed path, and each sensor's last
position. The formats (GeoJSON, KML, CoT) only serialise a scene.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rfsas_hw.exports.run import BearingLine, RunLog
from rfsas_hw.exports.shapes import (
    BEARING_LENGTH_M,
    ELLIPSE_SIGMA,
    Ellipse,
    bearing_end,
    ellipse_of,
)
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.records import Fix

Array = npt.NDArray[np.float64]

__all__ = ["BearingMark", "FixMark", "Scene", "SensorMark", "TrackPath", "build_scene"]


@dataclass(frozen=True, slots=True)
class FixMark:
    """A fix on the globe."""

    fix: Fix
    lat_deg: float
    lon_deg: float
    ellipse: Ellipse | None
    """The error ellipse (None: covariance not usable)."""
    ring_deg: Array | None
    """The ellipse's closed ring, (n, 2) of (lat °, lon °)."""


@dataclass(frozen=True, slots=True)
class BearingMark:
    """A bearing ray on the globe, from the sensor outwards."""

    bearing: BearingLine
    start_deg: tuple[float, float]
    """(lat °, lon °) of the sensor."""
    end_deg: tuple[float, float]
    """(lat °, lon °) of the ray's end."""
    length_m: float


@dataclass(frozen=True, slots=True)
class TrackPath:
    """One emitter's track as a timed path."""

    emitter: str
    t_ns: npt.NDArray[np.int64]
    lat_deg: Array
    lon_deg: Array
    speed_mps: Array
    """Track speed at each point, m/s (NaN where unknown)."""
    course_deg: Array
    """Compass course at each point, degrees (NaN where unknown)."""


@dataclass(frozen=True, slots=True)
class SensorMark:
    """A sensor's last known position."""

    sensor_id: str
    t_ns: int
    lat_deg: float
    lon_deg: float


@dataclass(frozen=True, slots=True)
class Scene:
    """Everything of a run an export draws."""

    origin: SiteOrigin
    fixes: tuple[FixMark, ...]
    bearings: tuple[BearingMark, ...]
    tracks: tuple[TrackPath, ...]
    sensors: tuple[SensorMark, ...]


def _geo(origin: SiteOrigin, x: Array, y: Array) -> tuple[Array, Array]:
    lat, lon, _ = origin.to_geodetic(x, y, 0.0)
    return np.atleast_1d(lat), np.atleast_1d(lon)


def build_scene(
    run: RunLog,
    origin: SiteOrigin,
    *,
    flagged: bool = False,
    n_sigma: float = ELLIPSE_SIGMA,
    bearing_length_m: float = BEARING_LENGTH_M,
) -> Scene:
    """Place ``run`` on the globe at ``origin``.

    Args:
        run: the run log.
        origin: the site origin (usually ``run.origin``).
        flagged: also draw fixes the backend flagged (never used as positions).
        n_sigma: standard deviations of the drawn ellipses.
        bearing_length_m: length of the drawn bearing rays, metres.
    """
    fixes = [
        f for f in run.fixes if (f.ok or flagged) and math.isfinite(f.x_m) and math.isfinite(f.y_m)
    ]
    lat, lon = _geo(origin, np.array([f.x_m for f in fixes]), np.array([f.y_m for f in fixes]))
    fix_marks = []
    for i, f in enumerate(fixes):
        ell = ellipse_of(f.cov_xx_m2, f.cov_xy_m2, f.cov_yy_m2, n_sigma)
        ring = None
        if ell is not None:
            pts = ell.ring(f.x_m, f.y_m)
            rlat, rlon = _geo(origin, pts[:, 0], pts[:, 1])
            ring = np.column_stack([rlat, rlon])
            ring[-1] = ring[0]
        fix_marks.append(FixMark(f, float(lat[i]), float(lon[i]), ell, ring))

    rays = [b for b in run.bearings if all(math.isfinite(v) for v in (b.x_m, b.y_m, b.azimuth_deg))]
    ends = np.array([bearing_end(b.x_m, b.y_m, b.azimuth_deg, bearing_length_m) for b in rays])
    starts = np.array([(b.x_m, b.y_m) for b in rays])
    bearing_marks: list[BearingMark] = []
    sensors: dict[str, SensorMark] = {}
    if rays:
        slat, slon = _geo(origin, starts[:, 0], starts[:, 1])
        elat, elon = _geo(origin, ends[:, 0], ends[:, 1])
        for i, b in enumerate(rays):
            bearing_marks.append(
                BearingMark(
                    b,
                    (float(slat[i]), float(slon[i])),
                    (float(elat[i]), float(elon[i])),
                    bearing_length_m,
                )
            )
            sensors[b.sensor_id] = SensorMark(b.sensor_id, b.t_ns, float(slat[i]), float(slon[i]))

    by_emitter: dict[str, list[tuple[int, float, float, float, float]]] = defaultdict(list)
    for a in run.assessments:
        # only tracked emitters have a velocity; the rest are single fixes, not paths
        if all(math.isfinite(v) for v in (a.x_m, a.y_m, a.vx_mps, a.vy_mps)):
            by_emitter[a.emitter].append((a.t_ns, a.x_m, a.y_m, a.vx_mps, a.vy_mps))
    tracks = []
    for emitter, rows in by_emitter.items():
        rows.sort()
        if len(rows) < 2:
            continue
        arr = np.array([r[1:] for r in rows], dtype=np.float64)
        tlat, tlon = _geo(origin, arr[:, 0], arr[:, 1])
        speed = np.hypot(arr[:, 2], arr[:, 3])
        course = np.degrees(np.arctan2(arr[:, 2], arr[:, 3])) % 360.0
        tracks.append(
            TrackPath(
                emitter,
                np.array([r[0] for r in rows], dtype=np.int64),
                tlat,
                tlon,
                speed,
                course,
            )
        )
    return Scene(
        origin=origin,
        fixes=tuple(fix_marks),
        bearings=tuple(bearing_marks),
        tracks=tuple(tracks),
        sensors=tuple(sensors.values()),
    )
