"""kraken:URL — a KrakenSDR's DOA_value.html polled over HTTP on loopback."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import numpy as np
import pytest

from rfsas_hw.errors import ConfigError, DataFormatError
from rfsas_hw.privacy import FixedNonce, MacHasher
from rfsas_hw.records import BearingBatch
from rfsas_hw.sources import open_source
from rfsas_hw.sources.base import Source
from rfsas_hw.sources.kraken import KrakenLine, KrakenSource, kraken_url, parse_line
from rfsas_hw.sources.kraken_emulator import KrakenEmulator, KrakenServer, Vfo

# Lines in the documented "Kraken App" order: epoch ms, bearing (compass convention),
# confidence, power, frequency Hz, array, latency, station id, lat, lon, GPS heading,
# compass heading, heading sensor, four reserved fields, then the DoA spectrum.
SPECTRUM = ",".join(f"{v:.2f}" for v in np.linspace(0.0, 1.0, 360))
LINE_A = (
    f"1700000000123,315,8.52,-12.3,433920000,UCA,120,KRAKEN01,51.5,-0.12,0,0,GPS,R,R,R,R,{SPECTRUM}"
)
LINE_B = "1700000000123,45,2.10,-25.0,446006250,UCA,120,KRAKEN01,0,0,0,0,GPS,R,R,R,R"
KEY = b"k" * 32


class _Page:
    """A page a test sets, served at /DOA_value.html."""

    def __init__(self) -> None:
        self.body = ""


@pytest.fixture
def page() -> Iterator[tuple[_Page, str]]:
    holder = _Page()

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            body = holder.body.encode()
            self.send_response(200)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, format: str, *args: object) -> None:
            pass

    httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=httpd.serve_forever, args=(0.05,), daemon=True)
    thread.start()
    yield holder, f"http://127.0.0.1:{httpd.server_address[1]}/DOA_value.html"
    httpd.shutdown()
    thread.join(timeout=5)
    httpd.server_close()


def _read(src: Source[BearingBatch], seconds: float, want: int | None = None) -> list[BearingBatch]:
    out: list[BearingBatch] = []
    end = time.monotonic() + seconds
    while time.monotonic() < end and (want is None or sum(map(len, out)) < want):
        b = src.read(0.05)
        if b is not None and len(b):
            out.append(b)
    return out


def test_documented_line_parses() -> None:
    got = parse_line(LINE_A, 0)
    assert got == KrakenLine(0, 1700000000123, 315.0, 8.52, -12.3, 433920000, "KRAKEN01")
    assert isinstance(parse_line(LINE_B, 1), KrakenLine)  # no spectrum: still whole
    assert "fewer than the 17" in str(parse_line(LINE_A[:40], 0))
    assert "spectrum values, not 360" in str(parse_line(LINE_A[:-5], 0))
    assert "spectrum values, not 360" in str(parse_line(LINE_A + ",0.5", 0))
    assert "not" in str(parse_line(LINE_A.replace(",8.52,", ",x,"), 0))
    assert "outside" in str(parse_line(LINE_A.replace(",315,", ",400,"), 0))


def test_bearings_from_a_page(page: tuple[_Page, str]) -> None:
    holder, url = page
    holder.body = LINE_A + "\n" + LINE_B + "\n"
    hasher = MacHasher(FixedNonce(KEY))
    with KrakenSource(url, heading_deg=10.0, poll_s=0.05, hasher=hasher) as src:
        (batch,) = _read(src, 1.0, want=2)
        # the same frame polled again is a repeat, not a new bearing
        assert _read(src, 0.3) == []
        assert src.stats.extra["repeats"] >= 2
        holder.body = LINE_A.replace("1700000000123", "1700000000323", 1) + "\n"
        (again,) = _read(src, 1.0, want=1)
    assert batch.relative_deg.tolist() == [-45.0, 45.0]
    assert batch.azimuth_deg.tolist() == [325.0, 55.0]
    assert batch.sigma_deg.tolist() == [5.0, 5.0]
    want = [hasher.hash_one(433920000, int(batch.t_ns[0])), hasher.hash_one(446006250, 0)]
    assert batch.emitter[0] == want[0]
    assert batch.emitter[0] != batch.emitter[1]
    assert again.relative_deg.tolist() == [-45.0]


def test_sign_confidence_and_spec_options(page: tuple[_Page, str]) -> None:
    holder, url = page
    holder.body = LINE_A + "\n" + LINE_B + "\n"
    spec = f"kraken:{url}#sign=-1&min_confidence=5&floor=3&poll=0.05"
    with open_source(spec) as src:
        (batch,) = _read(src, 1.0, want=1)
        assert src.stats.skipped["low_confidence"] == 1
    assert batch.relative_deg.tolist() == [45.0]
    assert batch.sigma_deg.tolist() == [3.0]


def test_torn_lines_and_markup_are_counted(page: tuple[_Page, str]) -> None:
    holder, url = page
    holder.body = LINE_B + "\n" + LINE_A[:60]  # the unit caught mid-write
    with KrakenSource(url, poll_s=0.05) as src:
        (batch,) = _read(src, 1.0, want=1)
        assert len(batch) == 1
        assert src.stats.skipped["malformed"] >= 1
        holder.body = "<!DOCTYPE html><html>wrong port</html>"
        _read(src, 0.3)
        assert src.stats.extra["not_csv"] >= 1
    with (
        KrakenSource(url, poll_s=0.05, errors="raise") as strict,
        pytest.raises(DataFormatError, match="markup, not CSV"),
    ):
        _read(strict, 0.5)


def test_unreachable_unit_is_counted_not_fatal() -> None:
    with KrakenSource("http://127.0.0.1:9/DOA_value.html", poll_s=0.05, timeout_s=0.5) as src:
        assert _read(src, 0.3) == []
        assert src.stats.extra["poll_errors"] >= 1
        assert src.stats.errors


def test_urls_and_options() -> None:
    assert kraken_url("krakensdr") == "http://krakensdr:8081/DOA_value.html"
    assert kraken_url("10.0.0.5:8082") == "http://10.0.0.5:8082/DOA_value.html"
    with pytest.raises(ConfigError, match="only http"):
        KrakenSource("ftp://unit/DOA_value.html")
    with pytest.raises(ConfigError, match="keys sensor_id"):
        KrakenSource.from_spec("unit#colour=red")
    with pytest.raises(ConfigError, match="sign must be"):
        KrakenSource("unit", sign=0)


def test_emulator_with_torn_pages() -> None:
    emulator = KrakenEmulator(
        [Vfo.parse("433.92,45"), Vfo.parse("446.00625,300,30")], torn=0.3, seed=2
    )
    server = KrakenServer(emulator, rate_hz=40.0).start()
    try:
        with KrakenSource(server.url, poll_s=0.02) as src:
            batches = _read(src, 3.0, want=40)
            skipped = src.stats.skipped["malformed"]
    finally:
        server.stop()
    batch = np.concatenate([b.relative_deg for b in batches])
    emitters = np.concatenate([b.emitter for b in batches])
    assert len(batch) >= 40
    assert emulator.torn_pages > 0 and skipped > 0
    assert len(np.unique(emitters)) == 2
    near_45 = np.abs(batch - 45.0) < 10
    near_300 = np.abs(batch + 60.0) < 10
    assert np.all(near_45 | near_300)


def test_emulator_options_are_checked() -> None:
    with pytest.raises(ConfigError, match="FREQ_MHZ,BEARING"):
        Vfo.parse("433.92")
    with pytest.raises(ConfigError, match="at least one VFO"):
        KrakenEmulator([])
    with pytest.raises(ConfigError, match="rate must be positive"):
        KrakenServer(KrakenEmulator([Vfo(433.92, 0.0)]), rate_hz=0)
