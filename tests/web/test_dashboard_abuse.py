"""The dashboard against a hostile browser page and a descriptor-exhausting client: a
WebSocket from another site's page is refused, the live feed asks the token, and
held-open or half-sent requests are cut at a deadline and capped in number."""

from __future__ import annotations

import asyncio
import socket
import time
import urllib.error
import urllib.request
from collections.abc import Iterator

import pytest

from rfsas_hw.backend.site import SiteConfig
from rfsas_hw.web import site_payload
from rfsas_hw.web.limits import ConnectionLimits
from rfsas_hw.web.server import DashboardServer, same_origin
from rfsas_hw.web.state import DashboardState

aiohttp = pytest.importorskip("aiohttp", reason="needs the web extra (pip install .[web])")


def serve(token: str | None = None, limits: ConnectionLimits | None = None) -> DashboardServer:
    site = SiteConfig()
    state = DashboardState(site, clock=time.time_ns)
    server = DashboardServer(state, site_payload(site), "127.0.0.1", 0, token, limits)
    server.start()
    return server


@pytest.fixture
def open_server() -> Iterator[DashboardServer]:
    """On loopback without a token: what ``rfsas backend --web 8080`` runs."""
    server = serve()
    yield server
    server.stop()


async def ws_status(url: str, origin: str | None) -> int:
    headers = {} if origin is None else {"Origin": origin}
    async with aiohttp.ClientSession() as session:
        try:
            async with session.ws_connect(url, headers=headers) as ws:
                await ws.receive(timeout=5)  # the snapshot
                return 101
        except aiohttp.WSServerHandshakeError as err:
            return int(err.status)


def test_a_page_of_another_site_cannot_open_the_websocket(open_server: DashboardServer) -> None:
    port = open_server.port
    url = f"http://127.0.0.1:{port}/ws"
    # the attack: a page from elsewhere, open in the operator's browser, addresses loopback
    assert asyncio.run(ws_status(url, "https://attacker.example")) == 403
    assert asyncio.run(ws_status(url, f"http://127.0.0.1:{port + 1}")) == 403
    assert asyncio.run(ws_status(url, "null")) == 403
    # the dashboard's own page, and a client that sends no Origin (not a browser)
    assert asyncio.run(ws_status(url, f"http://127.0.0.1:{port}")) == 101
    assert asyncio.run(ws_status(url, None)) == 101


def test_same_origin() -> None:
    assert same_origin(None, "127.0.0.1:8080")
    assert same_origin("http://127.0.0.1:8080", "127.0.0.1:8080")
    assert same_origin("https://Dash.example:8443", "dash.example:8443")
    assert not same_origin("http://127.0.0.1:8081", "127.0.0.1:8080")
    assert not same_origin("file://", "127.0.0.1:8080")


def test_the_websocket_asks_the_token_from_loopback_too() -> None:
    server = serve(token="s3cret")
    try:
        base = f"http://127.0.0.1:{server.port}/ws"
        assert asyncio.run(ws_status(base, None)) == 403
        assert asyncio.run(ws_status(base + "?token=wrong", None)) == 403
        assert asyncio.run(ws_status(base + "?token=s3cret", None)) == 101
    finally:
        server.stop()


def get_status(url: str) -> int:
    try:
        with urllib.request.urlopen(url, timeout=10) as r:
            return int(r.status)
    except urllib.error.HTTPError as err:
        err.close()
        return int(err.code)


def closed_by_server(sock: socket.socket, timeout_s: float) -> bool:
    """True when the server closes ``sock`` (EOF or reset) within ``timeout_s``."""
    sock.settimeout(timeout_s)
    try:
        while sock.recv(4096):
            pass
    except TimeoutError:
        return False
    except ConnectionResetError:
        pass
    return True


def test_held_and_partial_requests_are_cut_and_capped() -> None:
    cap = 6
    server = serve(limits=ConnectionLimits(max_connections=cap, request_timeout_s=1.0))
    held: list[socket.socket] = []
    try:
        for i in range(cap):
            s = socket.create_connection(("127.0.0.1", server.port), timeout=5)
            if i % 2:
                s.sendall(b"GET /api/state HTTP/1.1\r\nHost: 127.0.0.1\r\n")  # never finished
            held.append(s)
        # one more than the cap is refused at once, before it could send anything
        extra = socket.create_connection(("127.0.0.1", server.port), timeout=5)
        held.append(extra)
        extra.settimeout(10)
        assert extra.recv(64).startswith(b"HTTP/1.1 503")
        # every held connection, idle or half-sent, is closed by the server at its deadline
        assert all(closed_by_server(s, 30.0) for s in held[:cap])
        gate = server.gate
        assert gate is not None and gate.refused >= 1 and gate.timed_out >= cap
        # and the dashboard is reachable again
        deadline = time.monotonic() + 30
        while gate.open and time.monotonic() < deadline:
            time.sleep(0.05)
        assert get_status(f"http://127.0.0.1:{server.port}/api/state") == 200
    finally:
        for s in held:
            s.close()
        server.stop()


def test_limits_are_checked() -> None:
    with pytest.raises(ValueError, match="max_connections"):
        ConnectionLimits(max_connections=0)
    with pytest.raises(ValueError, match="request_timeout_s"):
        ConnectionLimits(request_timeout_s=0)
