"""The live dashboard of a district: every unit, every backend's fixes and tracks.

The page and its server are the backend dashboard's (:mod:`rfsas_hw.web`, the ``web``
extra): the same access rules (loopback or the token, same-origin WebSockets), the
same connection cap and request deadline, the same bounded state. What differs is
where the state comes from: the district's units are the site's sensors (at their
poses, looking along their boresights), and each step the backends' reports
(:attr:`~rfsas_hw.city.live.StepOut.dashboard`: the fixes each made since its last
report and its current tracks) are taken in as one step of all of them, so the page
shows the tracks of every backend at once, each coloured by its worst advisory.

Nothing here holds a MAC address: emitters are the backends' keyed hashes.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

from rfsas_hw.backend.site import SiteConfig, SiteSensor
from rfsas_hw.city.live import StepOut
from rfsas_hw.city.placement import UnitSite
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.records import Assessment, Pose
from rfsas_hw.web import DashboardServer, DashboardState, site_payload
from rfsas_hw.web.server import parse_bind

__all__ = ["CityDashboard"]


class CityDashboard:
    """Serves the district's dashboard at ``bind`` from construction until :meth:`close`.

    Args:
        units: the district's units (rfsas frame).
        origin: the site origin of the frame.
        bind: ``PORT`` (on 127.0.0.1), ``HOST:PORT`` or ``[V6]:PORT``.
        token: access token for non-local clients (default: a random one when bound
            elsewhere than loopback).

    Raises:
        ConfigError: a bad address, or a port that cannot be bound.
        MissingDependencyError: aiohttp is not installed (the ``web`` extra).
    """

    def __init__(
        self,
        units: Sequence[UnitSite],
        origin: SiteOrigin,
        bind: str,
        token: str | None = None,
    ) -> None:
        host, port = parse_bind(bind)
        site = SiteConfig(
            origin=origin,
            sensors=tuple(
                SiteSensor(u.id, Pose(u.x_m, u.y_m, u.boresight_deg % 360.0)) for u in units
            ),
        )
        self._clock: Callable[[], int] = time.time_ns
        self.state = DashboardState(site, clock=lambda: self._clock())
        self._tracks: dict[str, list[Assessment]] = {}
        self.server = DashboardServer(self.state, site_payload(site), host, port, token)
        self.server.start()

    @property
    def url(self) -> str:
        """Where the page is (with the token, if there is one)."""
        return self.server.url

    def use_clock(self, clock: Callable[[], int]) -> None:
        """Age fixes and bearings on ``clock`` (the deployment's, UTC ns) from now on."""
        self._clock = clock

    def take(self, step: StepOut) -> None:
        """Take in one step of the distributed path (nothing when no backend reported)."""
        if not step.dashboard:
            return
        fixes = []
        for backend, new_fixes, assessments in step.dashboard:
            fixes += new_fixes
            self._tracks[backend] = assessments
        self.state.on_results(fixes, [a for each in self._tracks.values() for a in each])

    def close(self) -> None:
        """Stop serving; idempotent."""
        self.server.stop()
