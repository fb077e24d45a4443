"""A run log placed on the globe: what every export format draws, in WGS-84.

:class:`SceneStream` turns the local-metre records of a run log into geodetic
marks through :class:`~rfsas_hw.geo.SiteOrigin` as they are read (one
vectorised conversion per chunk of records): fixes with their error-ellipse
rings, bearing rays from the sensor, each emitter's track as a timed path, and
each sensor's last position. The formats (GeoJSON, KML, CoT) only serialise
what it gives.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rfsas_hw.exports.run import BearingLine, RunRecord
from rfsas_hw.exports.shapes import (
    BEARING_LENGTH_M,
    ELLIPSE_SIGMA,
    Ellipse,
    bearing_end,
    ellipse_of,
)
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.records import Assessment, Fix

Array = npt.NDArray[np.float64]

__all__ = [
    "BearingMark",
    "FixMark",
    "SceneCounts",
    "SceneStream",
    "SensorMark",
    "TrackPath",
]

CHUNK = 4096
"""Records converted to the globe per vectorised call."""


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


def _geo(origin: SiteOrigin, x: Array, y: Array) -> tuple[Array, Array]:
    lat, lon, _ = origin.to_geodetic(x, y, 0.0)
    return np.atleast_1d(lat), np.atleast_1d(lon)


@dataclass(frozen=True, slots=True)
class SceneCounts:
    """How much of a run an export drew."""

    fixes: int
    bearings: int
    tracks: int
    sensors: int


class _TrackRows:
    """One emitter's tracked states as compact columns (8 bytes a value)."""

    __slots__ = ("t_ns", "vx", "vy", "x", "y")

    def __init__(self) -> None:
        self.t_ns = array("q")
        self.x = array("d")
        self.y = array("d")
        self.vx = array("d")
        self.vy = array("d")


class SceneStream:
    """A run's records placed on the globe as they are read.

    :meth:`marks` takes the records once, in file order, and yields the fix
    and bearing marks in chunks of ``chunk`` records (one vectorised
    conversion per chunk; each kind stays in file order). What only the whole
    run tells is kept compact on the way and ready once :meth:`marks` is
    exhausted: each sensor's last position (:meth:`sensors`) and each tracked
    emitter's path (:meth:`tracks`, 40 bytes a state). Memory is bounded by
    the chunk, the sensors and the tracked states, not by the log.

    Args:
        records: the run's records (:meth:`~rfsas_hw.exports.run.RunLog.records`).
        origin: the site origin (usually the log's own).
        flagged: also draw fixes the backend flagged (never used as positions).
        n_sigma: standard deviations of the drawn ellipses.
        bearing_length_m: length of the drawn bearing rays, metres.
        chunk: records converted per call (None: :data:`CHUNK`).
    """

    def __init__(
        self,
        records: Iterable[RunRecord],
        origin: SiteOrigin,
        *,
        flagged: bool = False,
        n_sigma: float = ELLIPSE_SIGMA,
        bearing_length_m: float = BEARING_LENGTH_M,
        chunk: int | None = None,
    ) -> None:
        self.origin = origin
        self.flagged = flagged
        self.n_sigma = n_sigma
        self.bearing_length_m = bearing_length_m
        self.chunk = CHUNK if chunk is None else chunk
        self.fixes = 0
        """Fix marks yielded so far."""
        self.bearings = 0
        """Bearing marks yielded so far."""
        self._records = records
        self._sensors: dict[str, SensorMark] = {}
        self._tracks: dict[str, _TrackRows] = {}

    def marks(self) -> Iterator[FixMark | BearingMark]:
        """The fix and bearing marks of the records (see the class docstring)."""
        fixes: list[Fix] = []
        rays: list[BearingLine] = []
        for r in self._records:
            if isinstance(r, Fix):
                if (r.ok or self.flagged) and math.isfinite(r.x_m) and math.isfinite(r.y_m):
                    fixes.append(r)
                    if len(fixes) >= self.chunk:
                        yield from self._fix_marks(fixes)
                        fixes = []
            elif isinstance(r, BearingLine):
                if all(math.isfinite(v) for v in (r.x_m, r.y_m, r.azimuth_deg)):
                    rays.append(r)
                    if len(rays) >= self.chunk:
                        yield from self._bearing_marks(rays)
                        rays = []
            elif isinstance(r, Assessment):
                self._track(r)
        yield from self._fix_marks(fixes)
        yield from self._bearing_marks(rays)

    def _fix_marks(self, fixes: list[Fix]) -> list[FixMark]:
        if not fixes:
            return []
        origin = self.origin
        lat, lon = _geo(origin, np.array([f.x_m for f in fixes]), np.array([f.y_m for f in fixes]))
        marks = []
        for i, f in enumerate(fixes):
            ell = ellipse_of(f.cov_xx_m2, f.cov_xy_m2, f.cov_yy_m2, self.n_sigma)
            ring = None
            if ell is not None:
                pts = ell.ring(f.x_m, f.y_m)
                rlat, rlon = _geo(origin, pts[:, 0], pts[:, 1])
                ring = np.column_stack([rlat, rlon])
                ring[-1] = ring[0]
            marks.append(FixMark(f, float(lat[i]), float(lon[i]), ell, ring))
        self.fixes += len(marks)
        return marks

    def _bearing_marks(self, rays: list[BearingLine]) -> list[BearingMark]:
        if not rays:
            return []
        length = self.bearing_length_m
        ends = np.array([bearing_end(b.x_m, b.y_m, b.azimuth_deg, length) for b in rays])
        starts = np.array([(b.x_m, b.y_m) for b in rays])
        slat, slon = _geo(self.origin, starts[:, 0], starts[:, 1])
        elat, elon = _geo(self.origin, ends[:, 0], ends[:, 1])
        marks = []
        for i, b in enumerate(rays):
            start = (float(slat[i]), float(slon[i]))
            marks.append(BearingMark(b, start, (float(elat[i]), float(elon[i])), length))
            self._sensors[b.sensor_id] = SensorMark(b.sensor_id, b.t_ns, *start)
        self.bearings += len(marks)
        return marks

    def _track(self, a: Assessment) -> None:
        # only tracked emitters have a velocity; the rest are single fixes, not paths
        if not all(math.isfinite(v) for v in (a.x_m, a.y_m, a.vx_mps, a.vy_mps)):
            return
        rows = self._tracks.get(a.emitter)
        if rows is None:
            rows = self._tracks[a.emitter] = _TrackRows()
        rows.t_ns.append(a.t_ns)
        rows.x.append(a.x_m)
        rows.y.append(a.y_m)
        rows.vx.append(a.vx_mps)
        rows.vy.append(a.vy_mps)

    def sensors(self) -> tuple[SensorMark, ...]:
        """Each sensor's last position, in the order the sensors first appeared."""
        return tuple(self._sensors.values())

    def n_tracks(self) -> int:
        """Tracks :meth:`tracks` gives (emitters tracked at two times or more)."""
        return sum(len(rows.t_ns) >= 2 for rows in self._tracks.values())

    def tracks(self) -> Iterator[TrackPath]:
        """Each tracked emitter's path in time order, emitters in order of first
        appearance (one with a single tracked state is no path)."""
        for emitter, rows in self._tracks.items():
            if len(rows.t_ns) < 2:
                continue
            t_ns = np.frombuffer(rows.t_ns, dtype=np.int64)
            cols = [np.frombuffer(c, dtype=np.float64) for c in (rows.x, rows.y, rows.vx, rows.vy)]
            # time order; equal times in the order of their states' values, as sorting rows does
            order = np.lexsort((cols[3], cols[2], cols[1], cols[0], t_ns))
            x, y, vx, vy = (c[order] for c in cols)
            tlat, tlon = _geo(self.origin, x, y)
            speed = np.hypot(vx, vy)
            course = np.degrees(np.arctan2(vx, vy)) % 360.0
            yield TrackPath(emitter, t_ns[order], tlat, tlon, speed, course)

    def counts(self) -> SceneCounts:
        """What was drawn (complete once :meth:`marks` is exhausted)."""
        return SceneCounts(self.fixes, self.bearings, self.n_tracks(), len(self._sensors))
