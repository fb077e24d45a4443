"""The dashboard's web server: a read-only page with live updates over a WebSocket.

Served by aiohttp (the ``web`` extra) on its own thread and event loop, so the
backend's loop stays as it is. Routes, all ``GET``:

- ``/``: the page (hand-written HTML, JavaScript and SVG; nothing fetched from
  the internet unless the site names a tile server), with the site and the
  latest snapshot inside it (a JSON data block), so it is drawn before the
  WebSocket delivers;
- ``/static/{name}``: its script and style sheet;
- ``/api/site``: the site (origin, map in local metres, declared sensors, tile URL);
- ``/api/state``: the latest :meth:`~rfsas_hw.web.state.DashboardState.snapshot`;
- ``/ws``: a WebSocket that sends the snapshot at once and after every backend step.

Access: a request from a loopback address whose ``Host`` is a loopback name
is served; any other needs the token (``?token=…`` or ``Authorization:
Bearer …``) and is refused with 403 without it. The ``Host`` check keeps a
web page elsewhere from reaching a localhost dashboard through DNS rebinding.
Bound to anything but loopback, the server always has a token (a random one
unless given).

A request whose ``Origin`` is not this server (a browser sends it with every
WebSocket and cross-site request) is refused with 403, so a web page open in the
operator's browser cannot read the live snapshot over ``/ws``. The WebSocket
asks the token whenever the server has one, from loopback too (the page passes
it on).

Connections are admitted by :class:`~rfsas_hw.web.limits.ConnectionGate`: at
most ``limits.max_connections`` open, and plain HTTP ones closed
``limits.request_timeout_s`` after they were accepted (idle or partial requests
included).

A malformed request (bad request line, header or length) is answered 400 by
aiohttp and logged as one warning line naming the peer, not as a traceback on the
operator's console (:class:`OneLineLog`).
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import json
import logging
import secrets
import threading
from importlib import resources
from typing import Any
from urllib.parse import urlsplit

from rfsas_hw.errors import ConfigError
from rfsas_hw.optional import require
from rfsas_hw.web.limits import ConnectionGate, ConnectionLimits
from rfsas_hw.web.state import DashboardState

log = logging.getLogger(__name__)

STATIC_FILES = {"app.js": "text/javascript", "style.css": "text/css"}
LOOPBACK_NAMES = {"localhost", "localhost.", "ip6-localhost"}

__all__ = ["DashboardServer", "OneLineLog", "first_state_block", "is_loopback", "parse_bind"]


def is_loopback(host: str | None) -> bool:
    """True for ``localhost`` and loopback addresses (``127.0.0.0/8``, ``::1``)."""
    if not host:
        return False
    name = host.strip("[]").lower()
    if name in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(name.split("%")[0]).is_loopback
    except ValueError:
        return False


def parse_bind(text: str) -> tuple[str, int]:
    """``PORT``, ``HOST:PORT`` or ``[V6]:PORT`` to (host, port); the host defaults to 127.0.0.1.

    Raises:
        ConfigError: not a port in 0–65535 (0: any free port).
    """
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = "127.0.0.1", text
    host = host.strip("[]") or "127.0.0.1"
    try:
        number = int(port)
    except ValueError:
        number = -1
    if not 0 <= number <= 65535:
        raise ConfigError(f"--web {text!r}: expected [HOST:]PORT with a port in 0-65535")
    return host, number


class OneLineLog(logging.LoggerAdapter):  # type: ignore[type-arg]
    """The logger handed to aiohttp's request handler: what it reports as an exception
    (a malformed request, a handler that failed) becomes one warning line with the
    error's text, without a traceback."""

    def exception(self, msg: object, *args: object, exc_info: Any = None, **kw: Any) -> None:
        """Log ``msg % args`` and the error's text on one line, at warning level."""
        err = exc_info if isinstance(exc_info, BaseException) else None
        text = str(msg) % args if args else str(msg)
        if err is not None:
            detail = " ".join(str(err).split()) or type(err).__name__
            text = f"{text}: {detail}"
        self.logger.warning("dashboard: %s", text)


def first_state_block(site: dict[str, Any], snapshot: dict[str, Any]) -> str:
    """The page's first state: the site and a snapshot as a JSON data block (``<script
    type="application/json">``, never executed, so the content security policy holds).
    ``<``, ``>`` and ``&`` are escaped, so no value can close the element."""
    text = json.dumps({"site": site, "state": snapshot}, allow_nan=False)
    for raw, escaped in (("<", "\\u003c"), (">", "\\u003e"), ("&", "\\u0026")):
        text = text.replace(raw, escaped)
    return f'<script type="application/json" id="first-state">{text}</script>'


def _host_of(header: str) -> str:
    return urlsplit(f"//{header}").hostname or ""


def same_origin(origin: str | None, host_header: str) -> bool:
    """True when a request's ``Origin`` (None: not sent, as by non-browser clients) is the
    page this server serves: ``http(s)://`` plus the request's own ``Host``."""
    if origin is None:
        return True
    parts = urlsplit(origin)
    return parts.scheme in ("http", "https") and parts.netloc.lower() == host_header.lower()


class DashboardServer:
    """Serves the dashboard of ``state`` (see the module docstring).

    Args:
        state: what the page shows.
        site: the ``/api/site`` payload.
        host: address to bind (default loopback).
        port: TCP port (0: any free one).
        token: access token for non-local clients and the WebSocket (default: none
            on loopback, a random one elsewhere).
        limits: connection cap and request deadline (default :class:`ConnectionLimits`).

    Raises:
        MissingDependencyError: aiohttp is not installed.
    """

    def __init__(
        self,
        state: DashboardState,
        site: dict[str, Any],
        host: str = "127.0.0.1",
        port: int = 0,
        token: str | None = None,
        limits: ConnectionLimits | None = None,
    ) -> None:
        self._web = require("aiohttp.web")
        self.limits = limits or ConnectionLimits()
        self.gate: ConnectionGate | None = None
        """Admits connections once serving (its counters: open, refused, timed out)."""
        self.state = state
        self.site = site
        self.host = host
        self.port = port
        if not token and not is_loopback(host):  # '' is no token either: never open
            token = secrets.token_urlsafe(18)
        self.token = token
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._stop: asyncio.Event | None = None
        self._clients: set[Any] = set()
        self._pending = False
        self._csp = self._policy(site.get("tiles"))

    @staticmethod
    def _policy(tiles: str | None) -> str:
        img = "'self' data:"
        if tiles:
            parts = urlsplit(tiles)
            img += f" {parts.scheme}://{parts.netloc}"
        return (
            "default-src 'none'; script-src 'self'; style-src 'self'; "
            f"img-src {img}; connect-src 'self'; base-uri 'none'; frame-ancestors 'none'"
        )

    @property
    def url(self) -> str:
        """Where the page is, with the token if there is one."""
        host = self.host if ":" not in self.host else f"[{self.host}]"
        shown = "127.0.0.1" if host in ("0.0.0.0", "[::]") else host
        query = f"?token={self.token}" if self.token else ""
        return f"http://{shown}:{self.port}/{query}"

    def allows(self, remote: str | None, host_header: str, given: str | None) -> bool:
        """Whether a request from ``remote`` with this ``Host`` and token is served."""
        if self._token_ok(given):
            return True
        return is_loopback(remote) and is_loopback(_host_of(host_header))

    def _token_ok(self, given: str | None) -> bool:
        return bool(self.token and given and secrets.compare_digest(given, self.token))

    def start(self, timeout_s: float = 10.0) -> None:
        """Bind and serve on a thread of its own; returns once listening.

        Raises:
            ConfigError: the address cannot be bound (in use, not local, no permission).
        """
        self._thread = threading.Thread(target=self._run, name="rfsas-dashboard", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout_s):
            raise ConfigError(f"dashboard on {self.host}:{self.port}: did not start")
        if self._error is not None:
            raise ConfigError(
                f"dashboard on {self.host}:{self.port}: cannot listen: {self._error}"
            ) from self._error
        self.state.listeners.append(self.notify)

    def notify(self) -> None:
        """A new step was taken in: push the snapshot to every client (any thread)."""
        loop = self._loop
        if loop is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(self._schedule)

    def stop(self) -> None:
        """Close every connection and stop serving; idempotent."""
        with contextlib.suppress(ValueError):
            self.state.listeners.remove(self.notify)
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(stop.set)
        if self._thread is not None:
            self._thread.join(10.0)
            self._thread = None

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            serving = loop.run_until_complete(self._serve())
        except BaseException as err:
            self._error = err
            self._ready.set()
            loop.close()
            return
        self._ready.set()
        try:
            assert self._stop is not None
            loop.run_until_complete(self._stop.wait())
            loop.run_until_complete(self._shutdown(serving))
        finally:
            loop.close()

    async def _serve(self) -> Any:
        web = self._web
        self._stop = asyncio.Event()

        @web.middleware  # type: ignore[untyped-decorator]
        async def guard(request: Any, handler: Any) -> Any:
            return await self.guard(request, handler)

        async def headers(request: Any, response: Any) -> None:
            response.headers["Content-Security-Policy"] = self._csp
            response.headers["X-Content-Type-Options"] = "nosniff"
            # the token may be in the page's URL: never send it to a tile server
            response.headers["Referrer-Policy"] = "no-referrer"
            response.headers["Cache-Control"] = "no-store"

        app = web.Application(middlewares=[guard])
        app.on_response_prepare.append(headers)
        app.router.add_get("/", self._index)
        app.router.add_get("/static/{name}", self._static)
        app.router.add_get("/api/site", self._site)
        app.router.add_get("/api/state", self._state)
        app.router.add_get("/ws", self._ws)
        runner = web.AppRunner(app, access_log=None, logger=OneLineLog(log, {}))
        await runner.setup()
        self.gate = ConnectionGate(runner.server, self.limits)
        listener = await asyncio.get_running_loop().create_server(
            self.gate, self.host, self.port, reuse_address=True
        )
        if self.port == 0 and listener.sockets:
            self.port = int(listener.sockets[0].getsockname()[1])
        return runner, listener

    async def guard(self, request: Any, handler: Any) -> Any:
        """The access check of every request (see the module docstring): 403 or ``handler``."""
        given = request.query.get("token")
        auth = request.headers.get("Authorization", "")
        if auth.startswith("Bearer "):
            given = auth[7:].strip()
        host = request.headers.get("Host", "")
        if not same_origin(request.headers.get("Origin"), host):
            return self._web.json_response(
                {"error": "forbidden: a request from another site's page"}, status=403
            )
        if not self.allows(request.remote, host, given):
            return self._web.json_response(
                {"error": "forbidden: a token is needed from another host"}, status=403
            )
        if request.path == "/ws" and self.token and not self._token_ok(given):
            return self._web.json_response(
                {"error": "forbidden: the live feed needs the token"}, status=403
            )
        return await handler(request)

    async def _shutdown(self, serving: tuple[Any, asyncio.Server]) -> None:
        runner, listener = serving
        listener.close()
        for ws in list(self._clients):
            with contextlib.suppress(Exception):
                await ws.close(code=1001, message=b"server stopping")
        await runner.cleanup()

    @staticmethod
    def _asset(name: str) -> bytes:
        return (resources.files("rfsas_hw.web") / "static" / name).read_bytes()

    async def _index(self, request: Any) -> Any:
        page = self._asset("index.html").decode()
        block = first_state_block(self.site, self.state.snapshot())
        page = page.replace("</head>", f"{block}\n</head>", 1)
        return self._web.Response(text=page, content_type="text/html")

    async def _static(self, request: Any) -> Any:
        name = request.match_info["name"]
        if name not in STATIC_FILES:
            raise self._web.HTTPNotFound()
        return self._web.Response(body=self._asset(name), content_type=STATIC_FILES[name])

    async def _site(self, request: Any) -> Any:
        return self._web.json_response(self.site)

    async def _state(self, request: Any) -> Any:
        return self._web.Response(text=self._snapshot_text(), content_type="application/json")

    def _snapshot_text(self) -> str:
        return json.dumps(self.state.snapshot(), allow_nan=False)

    async def _ws(self, request: Any) -> Any:
        ws = self._web.WebSocketResponse(heartbeat=10.0)
        await ws.prepare(request)
        if self.gate is not None:
            self.gate.keep(request.transport)  # upgraded: its heartbeat watches it now
        self._clients.add(ws)
        try:
            await ws.send_str(self._snapshot_text())
            async for _ in ws:
                pass  # read-only: whatever a client sends is ignored
        finally:
            self._clients.discard(ws)
        return ws

    def _schedule(self) -> None:
        if self._pending or not self._clients:
            return
        self._pending = True
        asyncio.get_running_loop().create_task(self._broadcast())

    async def _broadcast(self) -> None:
        self._pending = False
        text = self._snapshot_text()
        for ws in list(self._clients):
            try:
                await asyncio.wait_for(ws.send_str(text), 2.0)
            except Exception:
                self._clients.discard(ws)
                with contextlib.suppress(Exception):
                    await ws.close()
