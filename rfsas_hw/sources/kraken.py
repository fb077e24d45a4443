"""``kraken:URL`` — bearings from a KrakenSDR direction finder's network output.

In its "Kraken App" data format the KrakenSDR software rewrites
``http://<unit>:8081/DOA_value.html`` every update period with one CSV line
per active VFO, in this order (fields 0…16, then the 360-value DoA spectrum)::

    epoch_ms, bearing_deg, confidence, power_db, freq_hz, array (UCA/ULA/Custom),
    latency_ms, station_id, lat, lon, gps_heading, compass_heading,
    heading_sensor, R, R, R, R, <spectrum values …>

The bearing is the DoA spectrum's peak in compass convention relative to the
array (0…359, 90 = to the right), written as ``360 − θ`` of the unit-circle
angle θ. This driver polls the page, reads each whole line and drops the
rest: the file is rewritten in place, so a poll can catch a line cut short
or with the tail of the previous, longer frame; such lines (fewer than 17
fields, or a spectrum of other than 0 or 360 values), and lines with a
field that is not a number where one is due, are counted as malformed. A
line whose timestamp is not newer than that VFO's last one is the same
frame seen again (counted, not an error). A page that is HTML or XML rather
than CSV (the wrong port or output mode) is counted and named in the errors.

**Azimuth.** ``relative = sign · bearing`` (wrapped to ±180°), compass
azimuth ``heading_deg + relative``; ``sign = −1`` for a build that writes
the unit-circle angle instead. ``heading_deg`` also takes the constant
offset that users often find between a Kraken array's reference and north.

**σ.** The unit reports no σ: its "confidence" is the peak-to-average ratio
of the DoA spectrum. Every bearing gets ``floor_deg`` (5° by default, the
"several degrees" the KrakenSDR documentation gives for clear line of
sight); bearings whose confidence is below ``min_confidence`` are dropped
(``low_confidence``). Measure the floor on site and set it.

**Identity.** The unit does not identify the transmitter; the emitter id is
the keyed per-epoch hash (the same hash as every other source) of the VFO's
frequency in Hz, so bearings on one frequency associate within an epoch
and no plain identifier leaves the process. Times are host UTC at the poll.
"""

from __future__ import annotations

import logging
import math
import os
import time
import urllib.error
import urllib.request
from dataclasses import dataclass
from typing import Any

import numpy as np

from rfsas_hw.angles import wrap_deg_180, wrap_deg_360
from rfsas_hw.errors import ConfigError, DataFormatError
from rfsas_hw.privacy.hashing import FixedNonce, MacHasher, NonceUnavailableError
from rfsas_hw.records import BearingBatch
from rfsas_hw.sources.base import MAX_KEPT_ERRORS, BatchFilter, ErrorPolicy, Source
from rfsas_hw.sources.spec_options import split_spec

log = logging.getLogger(__name__)

FIXED_FIELDS = 17
"""Fields before the DoA spectrum."""
SPECTRUM_POINTS = 360
"""Values of a whole DoA spectrum (one per degree); a line carries all of them or none."""
MAX_BODY = 1 << 20
"""Largest page read, bytes (16 VFOs with 360-value spectra are ~60 kB)."""
DEFAULT_PATH = "/DOA_value.html"


@dataclass(frozen=True, slots=True)
class KrakenLine:
    """One VFO's line of ``DOA_value.html``."""

    vfo: int
    """Position of the line in the page (the writer emits active VFOs in order)."""
    t_ms: int
    """Unit time, UNIX epoch milliseconds."""
    bearing_deg: float
    """DoA as written, degrees 0…360."""
    confidence: float
    """Peak-to-average ratio of the DoA spectrum (higher is better)."""
    power_db: float
    """Channel power, dB relative to full scale."""
    freq_hz: int
    """VFO frequency, Hz."""
    station_id: str
    """The unit's station name."""


def parse_line(text: str, vfo: int) -> KrakenLine | str:
    """One CSV line, or why it is not a whole one."""
    fields = text.split(",")
    if len(fields) < FIXED_FIELDS:
        return f"{len(fields)} fields, fewer than the {FIXED_FIELDS} of a whole line"
    spectrum = len(fields) - FIXED_FIELDS
    if spectrum not in (0, SPECTRUM_POINTS):
        # cut short, or with the tail of the previous frame's longer line attached
        return f"{spectrum} spectrum values, not {SPECTRUM_POINTS}"
    try:
        t_ms = int(fields[0])
        bearing = float(fields[1])
        confidence = float(fields[2])
        power = float(fields[3])
        freq = float(fields[4])
        float(fields[6])
        for value in fields[FIXED_FIELDS:]:
            if value.strip():
                float(value)
    except ValueError:
        return "a field that should be a number is not"
    if not (0.0 <= bearing <= 360.0 and math.isfinite(confidence) and freq > 0):
        return "bearing outside 0..360, or no frequency"
    if not 0 < freq < 2**48:
        return "frequency out of range"
    return KrakenLine(vfo, t_ms, bearing, confidence, power, round(freq), fields[7].strip())


def kraken_url(arg: str) -> str:
    """``HOST[:PORT]`` or a full URL to the page's URL (port 8081 by default)."""
    if "://" in arg:
        return arg
    host = arg if ":" in arg.rsplit("]", 1)[-1] else f"{arg}:8081"
    return f"http://{host}{DEFAULT_PATH}"


class KrakenSource(Source[BearingBatch]):
    """Bearings polled from a KrakenSDR's ``DOA_value.html``.

    Args:
        url: the page's URL, or ``HOST[:PORT]``.
        sensor_id: id of the bearings.
        heading_deg: compass azimuth of the array's reference direction, degrees.
        sign: +1 for the compass-convention bearing the unit writes, −1 for unit-circle.
        floor_deg: σ of every bearing, degrees.
        min_confidence: bearings with a lower confidence are dropped.
        poll_s: seconds between polls.
        timeout_s: HTTP timeout, seconds.
        hasher: keyed id hash (the deployment's epoch nonces); None for a per-run key.

    Raises:
        ConfigError: a bad option.
    """

    scheme = "kraken"
    yields_bearings = True
    hashes_ids = True
    """Hashes transmitter ids itself: ``rfsas live`` hands it the deployment's hasher."""

    def __init__(
        self,
        url: str,
        *,
        sensor_id: str = "kraken",
        heading_deg: float = 0.0,
        sign: int = 1,
        floor_deg: float = 5.0,
        min_confidence: float = 0.0,
        poll_s: float = 0.2,
        timeout_s: float = 2.0,
        hasher: MacHasher | None = None,
        errors: ErrorPolicy = "skip",
        filter: BatchFilter | None = None,
    ) -> None:
        super().__init__(errors=errors, filter=filter)
        self._closed = True  # until every option is checked (no "never closed" warning)
        if sign not in (1, -1):
            raise ConfigError(f"kraken sign must be 1 or -1, got {sign}")
        if not (floor_deg > 0 and poll_s > 0 and timeout_s > 0):
            raise ConfigError("kraken floor, poll and timeout must be positive")
        self.url = kraken_url(url)
        if not self.url.startswith(("http://", "https://")):
            raise ConfigError(f"kraken URL {self.url!r}: only http:// and https:// are read")
        self.sensor_id = sensor_id
        self.heading_deg = float(heading_deg)
        self.sign = sign
        self.floor_deg = float(floor_deg)
        self.min_confidence = float(min_confidence)
        self.poll_s = float(poll_s)
        self.timeout_s = float(timeout_s)
        self.hasher = hasher or MacHasher(FixedNonce(os.urandom(32)))
        self._last_poll = -math.inf
        self._last_t: dict[int, int] = {}
        self.stats.extra.update(polls=0, poll_errors=0, repeats=0, not_csv=0, lines=0)
        self._closed = False

    @classmethod
    def from_spec(cls, arg: str, **options: Any) -> KrakenSource:
        """``kraken:URL[#key=value&…]``; keys: sensor_id, heading, sign, floor,
        min_confidence, poll.

        Raises:
            ConfigError: an unknown key or a malformed value.
        """
        url, options = split_spec(
            cls.scheme,
            arg,
            {
                "sensor_id": ("sensor_id", str),
                "heading": ("heading_deg", float),
                "sign": ("sign", int),
                "floor": ("floor_deg", float),
                "min_confidence": ("min_confidence", float),
                "poll": ("poll_s", float),
            },
            options,
        )
        return cls(url, **options)

    def _fetch(self) -> str | None:
        try:
            with urllib.request.urlopen(self.url, timeout=self.timeout_s) as resp:
                body: bytes = resp.read(MAX_BODY + 1)
        except (urllib.error.URLError, OSError, ValueError) as err:
            self.stats.extra["poll_errors"] += 1
            if len(self.stats.errors) < MAX_KEPT_ERRORS:
                self.stats.errors.append(f"{self.url}: {err}")
            log.debug("poll of %s failed: %s", self.url, err)
            return None
        if len(body) > MAX_BODY:
            self._bad("malformed", DataFormatError(f"{self.url}: page over {MAX_BODY} bytes"))
            return None
        return body.decode("utf-8", "replace")

    def _read_raw(self, timeout: float | None) -> BearingBatch | None:
        wait = self._last_poll + self.poll_s - time.monotonic()
        if wait > 0:
            time.sleep(min(wait, timeout if timeout is not None else wait))
            if self._last_poll + self.poll_s > time.monotonic():
                return None
        self._last_poll = time.monotonic()
        self.stats.extra["polls"] += 1
        text = self._fetch()
        if text is None:
            return None
        now = time.time_ns()
        body = text.strip()
        if body[:64].lower().startswith(("<!doctype", "<html", "<?xml", "<data", "<doa")):
            self.stats.extra["not_csv"] += 1
            self._bad("not_csv", DataFormatError(f"{self.url}: the page is markup, not CSV"))
            return None
        rel: list[float] = []
        freqs: list[int] = []
        for vfo, raw in enumerate(line for line in body.splitlines() if line.strip()):
            self.stats.extra["lines"] += 1
            got = parse_line(raw.strip(), vfo)
            if isinstance(got, str):
                self._bad("malformed", DataFormatError(f"{self.url}: VFO line {vfo}: {got}"))
                continue
            if got.t_ms <= self._last_t.get(vfo, -1):
                self.stats.extra["repeats"] += 1
                continue
            self._last_t[vfo] = got.t_ms
            if got.confidence < self.min_confidence:
                self.stats.skip("low_confidence")
                continue
            rel.append(float(wrap_deg_180(self.sign * got.bearing_deg)))
            freqs.append(got.freq_hz)
        if not rel:
            return None
        n = len(rel)
        t_ns = np.full(n, now, np.int64)
        try:
            emitter = self.hasher.hash_batch(np.asarray(freqs, np.uint64), t_ns)
        except NonceUnavailableError:
            self.stats.skip("no_nonce", count=n)
            return None
        relative = np.asarray(rel)
        return BearingBatch(
            sensor_id=self.sensor_id,
            t_ns=t_ns,
            azimuth_deg=np.asarray(wrap_deg_360(relative + self.heading_deg)),
            sigma_deg=np.full(n, self.floor_deg),
            snr_db=np.full(n, np.nan),
            channel=np.zeros(n, np.int16),
            emitter=emitter,
            relative_deg=relative,
        )


__all__ = ["KrakenLine", "KrakenSource", "kraken_url", "parse_line"]
