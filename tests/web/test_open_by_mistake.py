"""A dashboard is never open to other hosts by mistake, and the site's tile URL cannot
add directives to its Content-Security-Policy."""

from __future__ import annotations

import time

import pytest

pytest.importorskip("aiohttp", reason="needs the web extra (pip install .[web])")

from rfsas_hw.backend.site import site_from_mapping
from rfsas_hw.errors import ConfigError
from rfsas_hw.web.server import DashboardServer
from rfsas_hw.web.state import DashboardState


@pytest.mark.parametrize("token", [None, ""])
def test_an_empty_token_beyond_loopback_is_a_random_one(token: str | None) -> None:
    state = DashboardState(clock=time.time_ns)
    server = DashboardServer(state, {}, "0.0.0.0", 0, token)
    assert server.token and len(server.token) >= 16
    assert DashboardServer(state, {}, "127.0.0.1", 0, token).token in (None, "")


@pytest.mark.parametrize(
    "tiles",
    [
        "https://tile.example.org;script-src *;/{z}/{x}/{y}.png",
        "https://tile.example.org/{z}/{x}/{y}.png; script-src *",
        "https://tile.example.org 'unsafe-inline'/{z}/{x}/{y}.png",
    ],
)
def test_a_tile_url_that_would_inject_policy_is_refused(tiles: str) -> None:
    site = {"origin": {"lat_deg": 52.2, "lon_deg": 0.12}, "tiles": tiles}
    with pytest.raises(ConfigError, match="tiles"):
        site_from_mapping(site, "site")


def test_a_plain_tile_url_is_taken() -> None:
    tiles = "https://tile.example.org:8443/osm/{z}/{x}/{y}.png?key=abc-123"
    site = site_from_mapping({"origin": {"lat_deg": 52.2, "lon_deg": 0.12}, "tiles": tiles}, "s")
    assert site.tiles == tiles
