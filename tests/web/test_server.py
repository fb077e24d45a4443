"""The dashboard server without a browser: access rules, read-only routes, live pushes,
the site map, and no raw MAC in anything it serves."""

from __future__ import annotations

import asyncio
import json
import logging
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from rfsas_hw.backend.service import BackendConfig, BackendService
from rfsas_hw.backend.site import SiteConfig, SiteSensor
from rfsas_hw.errors import ConfigError
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.records import BearingBatch, Pose
from rfsas_hw.studies.demo import EXAMPLE_SCENARIO
from rfsas_hw.web import site_payload
from rfsas_hw.web.server import DashboardServer, is_loopback, parse_bind
from rfsas_hw.web.sitemap import load_site_map
from rfsas_hw.web.state import DashboardState

ORIGIN = SiteOrigin(52.2053, 0.1218, 12.0)
MAC = 0x3C22_FB4E_9107


def get(url: str, host: str | None = None, method: str = "GET") -> tuple[int, bytes]:
    req = urllib.request.Request(url, method=method)
    if host is not None:
        req.add_header("Host", host)
    try:
        with urllib.request.urlopen(req, timeout=5) as r:
            return int(r.status), r.read()
    except urllib.error.HTTPError as err:
        body = err.read()
        err.close()
        return int(err.code), body


@pytest.fixture
def served() -> Iterator[tuple[DashboardServer, BackendService]]:
    site = SiteConfig(
        origin=ORIGIN,
        sensors=(SiteSensor("rsu-a", Pose(-30.0, 10.0, 90.0), 60.0),),
        map=EXAMPLE_SCENARIO,
    )
    service = BackendService(BackendConfig(site=site), clock=time.time_ns)
    state = DashboardState(site, clock=service.clock, vehicle=lambda: service.vehicle)
    service.sinks.append(state)
    server = DashboardServer(state, site_payload(site), "127.0.0.1", 0, token="s3cret")
    server.start()
    yield server, service
    server.stop()


def feed(service: BackendService) -> None:
    now = time.time_ns()
    # the emitter id here is a hash; a raw MAC value must never come back out
    for sid, pose, az in (("rsu-a", Pose(-30, 10, 90), 90.0), ("rsu-b", Pose(0, -20, 0), 0.0)):
        service.on_bearings(
            BearingBatch(
                sid,
                np.array([now], np.int64),
                np.array([az]),
                np.array([1.0]),
                np.array([20.0]),
                np.array([6], np.int16),
                np.array([0x0123_4567_89AB_CDEF], np.uint64),
            ),
            pose,
        )
    service.step(now + 1)


@pytest.mark.extra("web")
def test_routes_are_read_only_and_local_only_without_token(
    served: tuple[DashboardServer, BackendService],
) -> None:
    server, service = served
    base = f"http://127.0.0.1:{server.port}"
    feed(service)
    status, page = get(base + "/")
    assert status == 200 and b"static/app.js" in page
    assert get(base + "/static/app.js")[0] == 200
    assert get(base + "/static/../server.py")[0] == 404
    assert get(base + "/api/state", method="POST")[0] == 405
    status, body = get(base + "/api/state")
    snap = json.loads(body)
    assert snap["fixes"] and snap["fixes"][0]["emitter"] == "0123456789abcdef"
    assert abs(snap["fixes"][0]["x_m"]) < 1e-6 and abs(snap["fixes"][0]["y_m"] - 10) < 1e-6
    assert snap["fixes"][0]["lat_deg"] == pytest.approx(52.2053 + 10 / 111_260, abs=1e-5)
    assert {s["id"] for s in snap["sensors"]} == {"rsu-a", "rsu-b"}
    # a page elsewhere reaching this server by DNS rebinding carries its own Host
    status, body = get(base + "/api/state", host="attacker.example")
    assert status == 403 and b"token" in body
    assert get(base + "/api/state?token=s3cret", host="attacker.example")[0] == 200
    assert get(base + "/api/state?token=wrong", host="attacker.example")[0] == 403


@pytest.mark.extra("web")
def test_non_local_clients_need_the_token(served: tuple[DashboardServer, BackendService]) -> None:
    server, _ = served
    assert not server.allows("192.0.2.7", "192.0.2.1:8080", None)
    assert not server.allows("192.0.2.7", "127.0.0.1:8080", "nope")
    assert server.allows("192.0.2.7", "192.0.2.1:8080", "s3cret")
    assert server.allows("::1", "[::1]:8080", None)
    assert server.allows("127.0.0.1", "localhost:8080", None)


@pytest.mark.extra("web")
def test_a_request_from_another_host_is_refused_without_the_token(
    served: tuple[DashboardServer, BackendService],
) -> None:
    from unittest import mock

    from aiohttp import web
    from aiohttp.test_utils import make_mocked_request

    server, _ = served

    async def handler(request: web.Request) -> web.Response:
        return web.Response(text="served")

    def from_peer(peer: str, path: str, headers: dict[str, str]) -> web.Request:
        transport = mock.Mock()
        transport.get_extra_info.side_effect = lambda key, default=None: (
            (peer, 50000) if key == "peername" else default
        )
        return make_mocked_request("GET", path, headers=headers, transport=transport)

    async def status(peer: str, path: str, headers: dict[str, str]) -> int:
        response = await server.guard(from_peer(peer, path, headers), handler)
        return int(response.status)

    async def check() -> None:
        lan = {"Host": "192.0.2.1:8080"}
        assert await status("192.0.2.7", "/api/state", lan) == 403
        # a forged loopback Host does not help a client that is not on this machine
        assert await status("192.0.2.7", "/api/state", {"Host": "127.0.0.1:8080"}) == 403
        assert await status("192.0.2.7", "/api/state?token=s3cret", lan) == 200
        bearer = {**lan, "Authorization": "Bearer s3cret"}
        assert await status("192.0.2.7", "/ws", bearer) == 200
        assert await status("127.0.0.1", "/api/state", {"Host": "127.0.0.1:8080"}) == 200

    asyncio.run(check())


@pytest.mark.extra("web")
def test_bound_elsewhere_always_has_a_token() -> None:
    site = SiteConfig()
    state = DashboardState(site, clock=time.time_ns)
    server = DashboardServer(state, site_payload(site), "0.0.0.0", 8080)
    assert server.token and len(server.token) >= 20 and f"?token={server.token}" in server.url
    local = DashboardServer(state, site_payload(site), "127.0.0.1", 8080)
    assert local.token is None and local.url == "http://127.0.0.1:8080/"


@pytest.mark.extra("web")
def test_websocket_sends_the_snapshot_then_every_step(
    served: tuple[DashboardServer, BackendService],
) -> None:
    import aiohttp

    server, service = served

    async def client() -> list[dict[str, object]]:
        got = []
        url = f"http://127.0.0.1:{server.port}/ws?token=s3cret"  # as the page passes it on
        async with aiohttp.ClientSession() as session, session.ws_connect(url) as ws:
            got.append(json.loads((await ws.receive(timeout=5)).data))
            await asyncio.get_running_loop().run_in_executor(None, feed, service)
            got.append(json.loads((await ws.receive(timeout=5)).data))
        return got

    first, second = asyncio.run(client())
    assert first["fixes"] == [] and second["fixes"]
    assert int(str(second["version"])) == int(str(first["version"])) + 1


@pytest.mark.extra("web")
def test_served_text_has_no_raw_mac(served: tuple[DashboardServer, BackendService]) -> None:
    server, service = served
    feed(service)
    base = f"http://127.0.0.1:{server.port}"
    mac_colons = ":".join(f"{b:02x}" for b in MAC.to_bytes(6, "big"))
    for path in ("/", "/api/site", "/api/state", "/static/app.js"):
        text = get(base + path)[1].decode().lower()
        # the scenario's emitters carry this MAC; its map gives buildings and roads only
        assert mac_colons not in text and mac_colons.replace(":", "") not in text


def test_site_map_from_a_scenario_and_from_geojson(tmp_path: Path) -> None:
    features = load_site_map(EXAMPLE_SCENARIO, None)
    assert [f.kind for f in features].count("building") == 4
    assert [f.kind for f in features].count("road") == 2
    corners = [ORIGIN.to_geodetic(x, y) for x, y in ((10, -60), (60, -60), (60, -10), (10, -10))]
    ring = [[float(lon), float(lat)] for lat, lon, _ in corners]
    doc = {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "properties": {"kind": "building", "name": "south-east"},
                "geometry": {"type": "Polygon", "coordinates": [[*ring, ring[0]]]},
            },
            {
                "type": "Feature",
                "properties": {"name": "lane"},
                "geometry": {"type": "LineString", "coordinates": ring[:2]},
            },
        ],
    }
    path = tmp_path / "site.geojson"
    path.write_text(json.dumps(doc))
    building, lane = load_site_map(path, ORIGIN)
    assert building.kind == "building" and building.closed and len(building.points) == 4
    assert np.allclose(building.points, [(10, -60), (60, -60), (60, -10), (10, -10)], atol=0.01)
    assert lane.kind == "line" and not lane.closed
    with pytest.raises(ConfigError, match="needs the site origin"):
        load_site_map(path, None)
    path.write_text(
        '{"type": "FeatureCollection", "features": [{"type": "Feature", '
        '"geometry": {"type": "Polygon", "coordinates": [[[500, 0], [1, 1]]]}}]}'
    )
    with pytest.raises(ConfigError, match="feature 0: a position is not"):
        load_site_map(path, ORIGIN)


@pytest.mark.parametrize(
    ("text", "expected"),
    [("8080", ("127.0.0.1", 8080)), ("0.0.0.0:80", ("0.0.0.0", 80)), ("[::1]:0", ("::1", 0))],
)
def test_parse_bind(text: str, expected: tuple[str, int]) -> None:
    assert parse_bind(text) == expected


def test_parse_bind_refuses_bad_ports() -> None:
    for bad in ("http", "host:99999", "host:"):
        with pytest.raises(ConfigError, match="--web"):
            parse_bind(bad)
    assert is_loopback("127.3.4.5") and is_loopback("localhost") and not is_loopback("10.0.0.1")


@pytest.mark.extra("web")
def test_the_page_comes_with_the_site_and_a_first_state(
    served: tuple[DashboardServer, BackendService],
) -> None:
    server, service = served
    feed(service)
    status, body = get(f"http://127.0.0.1:{server.port}/?token=s3cret")
    assert status == 200
    page = body.decode()
    start = page.index('<script type="application/json" id="first-state">')
    block = page[start:].split(">", 1)[1].split("</script>", 1)[0]
    first = json.loads(block)
    # drawn at once, before the WebSocket delivers: the map and the latest step
    assert first["site"]["sensors"][0]["id"] == "rsu-a"
    assert first["site"]["map"]
    assert first["state"]["version"] == 1 and first["state"]["fixes"]


def test_the_first_state_block_cannot_be_closed_by_a_value() -> None:
    from rfsas_hw.web.server import first_state_block

    block = first_state_block({"name": "</script><script>alert(1)</script>&"}, {})
    inner = block.split(">", 1)[1].rsplit("</script>", 1)[0]
    assert "<" not in inner and ">" not in inner and "&" not in inner
    assert json.loads(inner)["site"]["name"] == "</script><script>alert(1)</script>&"


@pytest.mark.extra("web")
def test_a_malformed_request_is_one_log_line_not_a_traceback(
    served: tuple[DashboardServer, BackendService], caplog: pytest.LogCaptureFixture
) -> None:
    import socket

    server, _ = served
    bad = (
        b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: twelve\r\n\r\n",
        b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nBad\x01Header: x\r\n\r\n",
    )
    with caplog.at_level(logging.DEBUG):
        for request in bad:
            with socket.create_connection(("127.0.0.1", server.port), timeout=5) as sock:
                sock.sendall(request)
                reply = sock.recv(4096)
                assert reply.split(b" ", 2)[1] == b"400"
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and len(_warnings(caplog)) < len(bad):
            time.sleep(0.05)
    warnings = _warnings(caplog)
    assert len(warnings) == len(bad)
    for record in warnings:
        assert record.exc_info is None or record.exc_info == (None, None, None)
        line = record.getMessage()
        assert "\n" not in line and "127.0.0.1" in line and "400" in line
    assert not [r for r in caplog.records if r.exc_info and r.levelno >= logging.WARNING]


def _warnings(caplog: pytest.LogCaptureFixture) -> list[logging.LogRecord]:
    return [r for r in caplog.records if r.levelno >= logging.WARNING]
