"""A software KrakenSDR: ``DOA_value.html`` served over HTTP on loopback, for tests and demos.

Every period the page is rewritten with one line per VFO in the unit's
"Kraken App" CSV layout (:mod:`rfsas_hw.sources.kraken`): the bearing plus
Gaussian noise, a confidence, the power, the frequency, the fixed fields and
a 360-value DoA spectrum with its peak at the bearing. On request a poll is
answered with a torn page (a line cut short, as when the unit is caught
mid-write) or a markup page (the wrong output mode).
"""

from __future__ import annotations

import math
import random
import threading
import time
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

from rfsas_hw.errors import ConfigError, SourceError
from rfsas_hw.sources.kraken import DEFAULT_PATH


@dataclass(frozen=True, slots=True)
class Vfo:
    """A transmitter the emulated unit is tuned to."""

    freq_mhz: float
    """Frequency, MHz."""
    bearing_deg: float
    """True bearing in the unit's compass convention, degrees 0…360."""
    confidence: float = 20.0
    """Confidence written with every line."""

    @classmethod
    def parse(cls, text: str) -> Vfo:
        """``FREQ_MHZ,BEARING[,CONFIDENCE]``, e.g. ``433.92,45``.

        Raises:
            ConfigError: malformed.
        """
        parts = text.split(",")
        try:
            if len(parts) not in (2, 3):
                raise ValueError("expected FREQ_MHZ,BEARING[,CONFIDENCE]")
            vfo = cls(float(parts[0]), float(parts[1]) % 360.0, *(float(p) for p in parts[2:]))
        except ValueError as err:
            raise ConfigError(f"VFO {text!r}: {err}") from err
        if not vfo.freq_mhz > 0:
            raise ConfigError(f"VFO {text!r}: frequency must be positive")
        return vfo


class KrakenEmulator:
    """Produces the page.

    Args:
        vfos: what the unit is tuned to.
        noise_deg: one-sigma bearing noise, degrees.
        torn: probability that a poll gets a page cut short.
        markup: serve an HTML page instead of CSV (the wrong output mode).
        station_id: the station name written in every line.
        seed: random seed.

    Raises:
        ConfigError: no VFOs.
    """

    def __init__(
        self,
        vfos: list[Vfo],
        *,
        noise_deg: float = 2.0,
        torn: float = 0.0,
        markup: bool = False,
        station_id: str = "EMULATED",
        seed: int = 0,
    ) -> None:
        if not vfos:
            raise ConfigError("the emulated KrakenSDR needs at least one VFO")
        self.vfos = vfos
        self.noise_deg = noise_deg
        self.torn = torn
        self.markup = markup
        self.station_id = station_id
        self._rng = random.Random(seed)
        self._lock = threading.Lock()
        self.page = ""
        self.frames = 0
        self.torn_pages = 0
        self.update()

    def line(self, vfo: Vfo, t_ms: int) -> str:
        """One VFO's CSV line."""
        rng = self._rng
        bearing = (vfo.bearing_deg + rng.gauss(0.0, self.noise_deg)) % 360.0
        spectrum = [
            math.exp(-0.5 * (((k - bearing + 180.0) % 360.0 - 180.0) / 8.0) ** 2)
            for k in range(360)
        ]
        fields = [
            str(t_ms),
            f"{round(bearing) % 360}",
            f"{vfo.confidence:.2f}",
            f"{-20.0 + rng.gauss(0.0, 0.5):.1f}",
            str(round(vfo.freq_mhz * 1e6)),
            "UCA",
            "120",
            self.station_id,
            "0.000000",
            "0.000000",
            "0",
            "0",
            "GPS",
            "R",
            "R",
            "R",
            "R",
        ]
        return ",".join(fields + [f"{v:.3f}" for v in spectrum])

    def update(self) -> None:
        """Rewrite the page for a new frame."""
        t_ms = time.time_ns() // 1_000_000
        page = "\n".join(self.line(v, t_ms) for v in self.vfos) + "\n"
        with self._lock:
            self.page = page
            self.frames += 1

    def serve(self) -> str:
        """The page as one poll sees it (maybe torn, or markup)."""
        if self.markup:
            return "<!DOCTYPE html><html><body>Kerberos App mode</body></html>\n"
        with self._lock:
            page = self.page
        if self._rng.random() < self.torn:
            self.torn_pages += 1
            return page[: self._rng.randrange(1, max(2, len(page) // 2))]
        return page


class KrakenServer:
    """Serves an emulator over HTTP on ``127.0.0.1`` and rewrites the page at ``rate_hz``.

    Args:
        emulator: the unit.
        port: TCP port (0: any free port).
        rate_hz: frames per second.

    Raises:
        SourceError: the port cannot be bound.
        ConfigError: a rate that is not positive.
    """

    def __init__(self, emulator: KrakenEmulator, port: int = 0, rate_hz: float = 5.0) -> None:
        if not rate_hz > 0:
            raise ConfigError(f"rate must be positive, got {rate_hz}")
        self.emulator = emulator
        self.period_s = 1.0 / rate_hz
        emu = emulator

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                if self.path.split("?", 1)[0] != DEFAULT_PATH:
                    self.send_error(404)
                    return
                body = emu.serve().encode("utf-8")
                self.send_response(200)
                self.send_header("Content-Type", "text/html")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, format: str, *args: object) -> None:
                pass  # the library never prints

        try:
            self.httpd = ThreadingHTTPServer(("127.0.0.1", port), Handler)
        except OSError as err:
            raise SourceError(f"cannot listen on 127.0.0.1:{port}: {err}") from err
        self.httpd.daemon_threads = True
        self.port = int(self.httpd.server_address[1])
        self.url = f"http://127.0.0.1:{self.port}{DEFAULT_PATH}"
        self.stop_event = threading.Event()
        self._threads: list[threading.Thread] = []

    def _frames(self, duration_s: float | None) -> None:
        start = time.monotonic()
        while not self.stop_event.wait(self.period_s):
            if duration_s is not None and time.monotonic() - start >= duration_s:
                break
            self.emulator.update()

    def run(self, duration_s: float | None = None) -> None:
        """Serve until stopped (or for ``duration_s`` seconds) in the calling thread."""
        http = threading.Thread(target=self.httpd.serve_forever, args=(0.05,), daemon=True)
        http.start()
        try:
            self._frames(duration_s)
        finally:
            self.httpd.shutdown()
            http.join(timeout=5)
            self.httpd.server_close()

    def start(self) -> KrakenServer:
        """Serve from background threads."""
        t = threading.Thread(target=self.run, name="kraken-emulator", daemon=True)
        t.start()
        self._threads.append(t)
        return self

    def stop(self) -> None:
        """Stop serving and release the port."""
        self.stop_event.set()
        for t in self._threads:
            t.join(timeout=5)
