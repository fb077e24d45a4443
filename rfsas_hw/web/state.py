"""What the dashboard shows, collected from the backend as it runs.

:class:`DashboardState` is a result sink of the
:class:`~rfsas_hw.backend.service.BackendService` (it also takes the bearings
as they arrive) and keeps, under a lock, just what the page draws: every
sensor with its field of view, the latest bearing of each sensor–emitter
pair, the latest fix of each emitter with its error ellipse, recent track
points, the vehicle with the worst advisory, a risk timeline and each
sensor's link health. :meth:`DashboardState.snapshot` gives all of it as one
JSON-ready mapping in local metres (with latitude/longitude beside fixes when
the site has an origin).

When every sensor's link is silent, the snapshot is ``stale``: its advisory is
``none`` whatever the coasting tracks still give, so the page never shows a
CAUTION or BRAKE (or a CLEAR) that no sensor backs any more.

Nothing here ever holds a MAC address: emitters are the backend's keyed
hashes, sensors their ids.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from rfsas_hw.backend.risk import ADVISORY_RANK
from rfsas_hw.backend.site import DEFAULT_FOV_DEG, SiteConfig
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.exports.shapes import ELLIPSE_SIGMA, ellipse_of
from rfsas_hw.records import Assessment, BearingBatch, Fix, Pose, emitter_hex

NS = 1_000_000_000
"""Worse advisories rank higher; the vehicle shows the worst over all emitters."""

__all__ = ["ADVISORY_RANK", "DashboardLimits", "DashboardState"]


@dataclass(frozen=True, slots=True)
class DashboardLimits:
    """How much history the dashboard keeps."""

    bearing_keep_s: float = 2.0
    """A bearing is drawn for this long after it was measured, seconds."""
    track_points: int = 120
    """Track points kept per emitter."""
    timeline_points: int = 600
    """Steps kept on the risk timeline (60 s at the default 0.1 s step)."""
    fix_keep_s: float = 10.0
    """A fix is drawn for this long after it was computed, seconds."""


def _num(value: float, digits: int = 3) -> float | None:
    v = float(value)
    return round(v, digits) if math.isfinite(v) else None


class DashboardState:
    """Collects what the page draws (see the module docstring); thread-safe.

    Args:
        site: the site (origin, declared sensors with their fields of view).
        clock: the backend's clock, UTC ns (for ageing bearings and fixes).
        vehicle: returns the backend's current vehicle state (or None).
        link_health: called after each step on the backend's thread; returns per-sender
            link health rows (``sensor_id``, ``state``,
            ``messages``, ``lost``, ``p50_ms``, ``p99_ms``, ``silent_for_s``).
        link_stats: returns the link's counters (``verified``, ``rejected.<reason>``).
        limits: how much history to keep.
    """

    def __init__(
        self,
        site: SiteConfig | None = None,
        *,
        clock: Callable[[], int],
        vehicle: Callable[[], VehicleState | None] = lambda: None,
        link_health: Callable[[], Sequence[Mapping[str, Any]]] = lambda: (),
        link_stats: Callable[[], Mapping[str, int]] = dict,
        limits: DashboardLimits | None = None,
    ) -> None:
        self.site = site or SiteConfig()
        self.clock = clock
        self.vehicle = vehicle
        self.link_health = link_health
        self.link_stats = link_stats
        self.limits = limits or DashboardLimits()
        self._lock = threading.Lock()
        self._poses: dict[str, Pose] = {s.id: s.pose for s in self.site.sensors}
        self._heard: set[str] = set()
        self._bearings: dict[tuple[str, str], dict[str, Any]] = {}
        self._fixes: dict[str, Fix] = {}
        self._tracks: dict[str, deque[tuple[float, float]]] = {}
        self._assessments: dict[str, Assessment] = {}
        self._timeline: deque[tuple[int, float | None, str]] = deque(
            maxlen=self.limits.timeline_points
        )
        self._links: list[dict[str, Any]] = []
        self._link_stats: dict[str, int] = {}
        self.version = 0
        """Grows by one with every backend step taken in."""
        self.listeners: list[Callable[[], None]] = []
        """Called (from the backend's thread) after every step taken in."""

    def on_bearings(self, bearings: BearingBatch, pose: Pose) -> None:
        """Take a sensor's bearings (a :class:`~rfsas_hw.backend.service.BearingSink`)."""
        sid = bearings.sensor_id
        with self._lock:
            self._poses[sid] = pose
            self._heard.add(sid)
            for i in range(len(bearings)):
                az = float(bearings.azimuth_deg[i])
                if not math.isfinite(az):
                    continue
                emitter = emitter_hex(int(bearings.emitter[i]))
                self._bearings[(sid, emitter)] = {
                    "sensor_id": sid,
                    "emitter": emitter,
                    "t_ns": int(bearings.t_ns[i]),
                    "x_m": _num(pose.x_m),
                    "y_m": _num(pose.y_m),
                    "azimuth_deg": _num(az, 2),
                    "sigma_deg": _num(bearings.sigma_deg[i], 2),
                }

    def on_results(self, fixes: Sequence[Fix], assessments: Sequence[Assessment]) -> None:
        """Take one backend step's fixes and assessments (a result sink)."""
        now = self.clock()
        # read on the backend's thread: the link's watch is not safe to share
        links = [dict(row) for row in self.link_health()]
        stats = dict(self.link_stats())
        with self._lock:
            self._links, self._link_stats = links, stats
            for fix in fixes:
                if math.isfinite(fix.x_m) and math.isfinite(fix.y_m):
                    self._fixes[fix.emitter] = fix
            self._assessments = {a.emitter: a for a in assessments}
            for a in assessments:
                if all(math.isfinite(v) for v in (a.x_m, a.y_m, a.vx_mps)):
                    track = self._tracks.setdefault(
                        a.emitter, deque(maxlen=self.limits.track_points)
                    )
                    track.append((round(a.x_m, 2), round(a.y_m, 2)))
            worst = max(
                (a.advisory for a in assessments),
                key=lambda v: ADVISORY_RANK.get(v, 0),
                default="none",
            )
            risks = [a.risk for a in assessments if math.isfinite(a.risk)]
            self._timeline.append((now, max(risks) if risks else None, worst))
            keep = now - int(self.limits.fix_keep_s * NS)
            for emitter in [e for e, f in self._fixes.items() if f.t_ns < keep]:
                del self._fixes[emitter]
            # emitter ids change every nonce epoch: bearings no longer drawn must go, or
            # the store grows by every (sensor, emitter) pair ever heard
            oldest = now - int(self.limits.bearing_keep_s * NS)
            for pair in [k for k, b in self._bearings.items() if b["t_ns"] < oldest]:
                del self._bearings[pair]
            for emitter in [e for e in self._tracks if e not in self._assessments]:
                del self._tracks[emitter]
            self.version += 1
        for listener in list(self.listeners):
            listener()

    def close(self) -> None:
        """Nothing to release (a result sink's close)."""

    def _fix_entries(self, fixes: Sequence[Fix]) -> list[dict[str, Any]]:
        """The page's view of ``fixes``; latitude/longitude of all in one conversion."""
        entries: list[dict[str, Any]] = []
        for fix in fixes:
            ell = ellipse_of(fix.cov_xx_m2, fix.cov_xy_m2, fix.cov_yy_m2, ELLIPSE_SIGMA)
            entries.append(
                {
                    "emitter": fix.emitter,
                    "t_ns": fix.t_ns,
                    "x_m": _num(fix.x_m),
                    "y_m": _num(fix.y_m),
                    "ok": fix.ok,
                    "status": fix.status,
                    "sensors": list(fix.sensors),
                    "ellipse": None
                    if ell is None
                    else {
                        "semi_major_m": _num(ell.semi_major_m),
                        "semi_minor_m": _num(ell.semi_minor_m),
                        "orientation_deg": _num(ell.orientation_deg, 2),
                        "n_sigma": ell.n_sigma,
                    },
                }
            )
        origin = self.site.origin
        if origin is not None and fixes:
            lat, lon, _ = origin.to_geodetic([f.x_m for f in fixes], [f.y_m for f in fixes])
            for entry, lat_deg, lon_deg in zip(entries, lat.tolist(), lon.tolist(), strict=True):
                entry["lat_deg"] = round(lat_deg, 8)
                entry["lon_deg"] = round(lon_deg, 8)
        return entries

    def snapshot(self) -> dict[str, Any]:
        """Everything the page draws, JSON-ready (see the module docstring)."""
        now = self.clock()
        vehicle = self.vehicle()
        with self._lock:
            health, stats = list(self._links), dict(self._link_stats)
            sensors = []
            for sid, pose in sorted(self._poses.items()):
                declared = self.site.sensor(sid)
                sensors.append(
                    {
                        "id": sid,
                        "x_m": _num(pose.x_m),
                        "y_m": _num(pose.y_m),
                        "heading_deg": _num(pose.heading_deg, 2),
                        "fov_deg": declared.fov_deg if declared else DEFAULT_FOV_DEG,
                        "heard": sid in self._heard,
                    }
                )
            oldest = now - int(self.limits.bearing_keep_s * NS)
            bearings = [b for b in self._bearings.values() if b["t_ns"] >= oldest]
            fixes = list(self._fixes.values())
            tracks = []
            for emitter, points in self._tracks.items():
                a = self._assessments.get(emitter)
                tracks.append(
                    {
                        "emitter": emitter,
                        "points": [list(p) for p in points],
                        "advisory": a.advisory if a else "none",
                        "p_collision": _num(a.p_collision, 4) if a else None,
                        "risk": _num(a.risk, 6) if a else None,
                    }
                )
            timeline = [[t, None if r is None else _num(r, 6), adv] for t, r, adv in self._timeline]
            stale = bool(health) and all(row.get("state") == "silent" for row in health)
            advisory = "none" if stale or not self._timeline else self._timeline[-1][2]
            version = self.version
        # built outside the lock: the backend's thread never waits for the page
        fix_entries = self._fix_entries(fixes)
        return {
            "version": version,
            "t_ns": now,
            "advisory": advisory,
            "stale": stale,
            "sensors": sensors,
            "bearings": bearings,
            "fixes": fix_entries,
            "tracks": tracks,
            "vehicle": None
            if vehicle is None
            else {
                "x_m": _num(vehicle.x_m),
                "y_m": _num(vehicle.y_m),
                "heading_deg": _num(vehicle.heading_deg, 2),
                "speed_mps": _num(vehicle.speed_mps, 2),
                "length_m": vehicle.length_m,
                "width_m": vehicle.width_m,
                "advisory": advisory,
            },
            "timeline": timeline,
            "links": [
                {k: (_num(v, 1) if isinstance(v, float) else v) for k, v in row.items()}
                for row in health
            ],
            "link_stats": stats,
        }
