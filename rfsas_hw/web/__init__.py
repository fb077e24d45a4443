"""The operator's live dashboard: ``rfsas backend … --web [HOST:]PORT``.

:class:`~rfsas_hw.web.state.DashboardState` collects what the backend
produces, :class:`~rfsas_hw.web.server.DashboardServer` serves it as a
read-only page with live WebSocket updates, and :func:`site_payload` says what
the site looks like (map, declared sensors, origin, tiles).
"""

from __future__ import annotations

import time
from typing import Any

from rfsas_hw.backend.service import BackendService
from rfsas_hw.backend.site import SiteConfig
from rfsas_hw.exports.shapes import ELLIPSE_SIGMA
from rfsas_hw.web.server import DashboardServer, parse_bind
from rfsas_hw.web.sitemap import load_site_map
from rfsas_hw.web.state import DashboardState

__all__ = ["DashboardServer", "DashboardState", "site_payload", "start_dashboard"]


def start_dashboard(
    service: BackendService,
    bind: str,
    *,
    latency: Any = None,
    token: str | None = None,
) -> DashboardServer:
    """Serve the live dashboard of ``service`` at ``bind`` (``[HOST:]PORT``).

    Adds a :class:`DashboardState` to the service's sinks and starts the server.

    Args:
        service: the backend service (its ``config.site`` gives map, origin, sensors).
        bind: ``PORT`` (on 127.0.0.1), ``HOST:PORT`` or ``[V6]:PORT``.
        latency: the receiver's :class:`~rfsas_hw.link.latency.LatencyWatch`, for link
            health per sensor (None: no link table).
        token: access token for non-local clients (default: a random one when bound
            elsewhere than loopback).

    Raises:
        ConfigError: a bad address, an unusable map file, or a port that cannot be bound.
        MissingDependencyError: aiohttp is not installed.
    """
    host, port = parse_bind(bind)
    site = service.config.site

    def health() -> list[dict[str, Any]]:
        if latency is None:
            return []
        rows = latency.snapshot(time.time_ns()).values()
        return [
            {
                "sensor_id": r.sender_id,
                "state": r.state.value,
                "messages": r.messages,
                "lost": r.lost,
                "p50_ms": r.p50_ms,
                "p99_ms": r.p99_ms,
                "silent_for_s": r.silent_for_s,
            }
            for r in rows
        ]

    def stats() -> dict[str, int]:
        return service.link_stats() if service.link_stats is not None else {}

    state = DashboardState(
        site,
        clock=service.clock,
        vehicle=lambda: service.vehicle,
        link_health=health,
        link_stats=stats,
    )
    server = DashboardServer(state, site_payload(site), host, port, token)
    server.start()
    service.sinks.append(state)
    return server


def site_payload(site: SiteConfig) -> dict[str, Any]:
    """The page's ``/api/site``: map features and declared sensors in local metres, the
    origin, metres per degree of latitude/longitude at it (to lay optional tiles
    under the map) and the tile URL.

    Raises:
        ConfigError: the map file is unreadable or malformed.
    """
    origin = site.origin
    features = [] if site.map is None else [f.as_dict() for f in load_site_map(site.map, origin)]
    scale = None
    if origin is not None:
        step = 1e-3
        east, north, _ = origin.to_local(
            [origin.lat_deg + step, origin.lat_deg], [origin.lon_deg, origin.lon_deg + step]
        )
        scale = {"lat": float(north[0]) / step, "lon": float(east[1]) / step}
    return {
        "origin": None
        if origin is None
        else {"lat_deg": origin.lat_deg, "lon_deg": origin.lon_deg, "height_m": origin.height_m},
        "m_per_deg": scale,
        "map": features,
        "tiles": site.tiles if origin is not None else None,
        "sensors": [
            {
                "id": s.id,
                "x_m": s.pose.x_m,
                "y_m": s.pose.y_m,
                "heading_deg": s.pose.heading_deg,
                "fov_deg": s.fov_deg,
            }
            for s in site.sensors
        ],
        "ellipse_sigma": ELLIPSE_SIGMA,
    }
