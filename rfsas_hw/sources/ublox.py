"""``ublox:URL`` — bearings from a u-blox BLE angle-of-arrival anchor (XPLR-AOA, ANT-B10).

The anchor's AT interface (115200 8N1 by default) prints one ``+UUDF`` event
per angle it computes::

    +UUDF:<tag>,<rssi_pol1>,<azimuth>,<elevation>,<rssi_pol2>,<channel>,
          "<anchor_id>","<user_str>",<timestamp_ms>[,<seq>[,<azimuth_raw>,<elevation_raw>]]

9 fields in the first firmware, 10 with the periodic-advertising sequence
number, 12 with raw angles switched on. ``<tag>`` is the tag's 6-byte BLE
address (12 hex digits), angles are whole degrees in −90…90 relative to the
antenna board, ``<rssi_pol2>`` is reserved (0) on some firmware. The same
port carries ``+STARTUP``, ``OK``/``ERROR``, command echo and ``+UUDFP`` tag
payloads; those are counted, not errors. Anything else, or an event with the
wrong field count or a value out of range, is counted as malformed. A unit in
binary output mode is detected (bytes that are not text) and refused with
an error that says how to switch it back.

**Azimuth.** ``relative = sign · azimuth`` degrees clockwise from the board's
boresight (``sign`` is a setting: the manual gives the convention only in a
figure), and the compass azimuth is ``boresight_deg + relative``.

**σ.** The unit reports no σ. This driver assigns
``σ² = floor² + σ_φ²`` with ``σ_φ = 1 / ((D/λ)·cos θ·√SNR)`` (the phase
interferometer of method.md §3, in radians), ``SNR`` the stronger
polarisation's RSSI above ``noise_floor_dbm`` (−103.9 dBm, the BLE threshold
of method.md §2), ``D/λ = spacing_wavelengths`` (0.5 for a half-wavelength
array) and ``cos θ`` held at or above cos 75° at the edges. ``floor`` (5° by
default) stands for multipath and the array's own error; measure it on site
against known tag positions and set it.

**Privacy.** The tag address is a raw MAC. It is hashed here, inside the
process, with the same keyed per-epoch hash as every other source; the
bearings carry only that id. Without a ``hasher`` a per-run random key is
used (ids unlinkable across runs).
"""

from __future__ import annotations

import csv
import math
import os
import time
from typing import Any, ClassVar

import numpy as np

from rfsas_hw.angles import wrap_deg_180, wrap_deg_360
from rfsas_hw.errors import ConfigError, DataFormatError, SourceError
from rfsas_hw.privacy.hashing import FixedNonce, MacHasher, NonceUnavailableError
from rfsas_hw.records import BearingBatch
from rfsas_hw.sources.base import BatchFilter, ErrorPolicy
from rfsas_hw.sources.serial_lines import SerialLineSource
from rfsas_hw.sources.spec_options import SpecKeys

MAX_LINE = 400
"""Longest line accepted, bytes (a 12-field event with two 30-character strings is ~130)."""
FIELD_COUNTS = (9, 10, 12)
"""Field counts of ``+UUDF`` events across firmware versions."""
BLE_NOISE_FLOOR_DBM = -103.9
"""Receiver threshold of BLE (method.md §2), dBm."""
BINARY_LINES = 3
"""Consecutive non-text lines after which the unit is taken to be in binary mode."""
_TEXT = frozenset(range(0x20, 0x7F)) | {0x09}
_MIN_COS = math.cos(math.radians(75.0))


def mac_from_hex(text: str) -> int:
    """A 12-hex-digit BLE address as an integer.

    Raises:
        ValueError: not 12 hex digits.
    """
    if len(text) != 12:
        raise ValueError("tag id is not 12 hex digits")
    return int(text, 16)


RSSI_MIN_DBM = -128
"""The lowest RSSI an event may carry (a signed byte, dBm); beyond it a line is bad."""


def sigma_from_rssi(
    rssi_dbm: float,
    azimuth_deg: float,
    *,
    floor_deg: float = 5.0,
    spacing_wavelengths: float = 0.5,
    noise_floor_dbm: float = BLE_NOISE_FLOOR_DBM,
) -> float:
    """One-sigma bearing error assigned to an event, degrees (see the module text)."""
    snr = 10.0 ** ((rssi_dbm - noise_floor_dbm) / 10.0)
    cos_t = max(math.cos(math.radians(azimuth_deg)), _MIN_COS)
    phase = math.degrees(1.0 / (spacing_wavelengths * cos_t * math.sqrt(max(snr, 1e-3))))
    return math.hypot(floor_deg, phase)


class UbloxSource(SerialLineSource):
    """Bearings from a u-blox AoA anchor's ``+UUDF`` events on a serial port or TCP bridge.

    Args:
        url: device path or pyserial URL (``/dev/ttyACM0``, ``socket://host:port``).
        baudrate: 115200 by default.
        sensor_id: id of the bearings.
        boresight_deg: compass azimuth of the board's boresight, degrees.
        sign: +1 when the unit's positive azimuth is clockwise seen from above, else −1.
        floor_deg: σ floor, degrees.
        spacing_wavelengths: antenna spacing over wavelength, for σ.
        hasher: keyed MAC hash (the deployment's epoch nonces); None for a per-run key.
        port_factory: opens the port (default :func:`serial.serial_for_url`).

    Raises:
        SourceError: the port cannot be opened.
        ConfigError: a bad option.
    """

    scheme = "ublox"
    device = "u-blox unit"
    max_line = MAX_LINE
    spec_keys: ClassVar[SpecKeys] = {
        "baud": ("baudrate", int),
        "sensor_id": ("sensor_id", str),
        "boresight": ("boresight_deg", float),
        "sign": ("sign", int),
        "floor": ("floor_deg", float),
        "spacing": ("spacing_wavelengths", float),
    }
    """``ublox:URL[#key=value&…]`` keys: baud, sensor_id, boresight, sign, floor, spacing."""
    yields_bearings = True
    hashes_ids = True
    """Hashes transmitter ids itself: ``rfsas live`` hands it the deployment's hasher."""

    def __init__(
        self,
        url: str,
        *,
        baudrate: int = 115_200,
        sensor_id: str = "ublox",
        boresight_deg: float = 0.0,
        sign: int = 1,
        floor_deg: float = 5.0,
        spacing_wavelengths: float = 0.5,
        hasher: MacHasher | None = None,
        port_factory: Any = None,
        errors: ErrorPolicy = "skip",
        filter: BatchFilter | None = None,
    ) -> None:
        super().__init__(errors=errors, filter=filter)
        self._closed = True
        if sign not in (1, -1):
            raise ConfigError(f"ublox sign must be 1 or -1, got {sign}")
        if not (floor_deg >= 0 and spacing_wavelengths > 0):
            raise ConfigError("ublox floor must be ≥ 0 and spacing > 0")
        self.sensor_id = sensor_id
        self.boresight_deg = float(boresight_deg)
        self.sign = sign
        self.floor_deg = float(floor_deg)
        self.spacing_wavelengths = float(spacing_wavelengths)
        self.hasher = hasher or MacHasher(FixedNonce(os.urandom(32)))
        self._line_no = 0
        self._binary_run = 0
        self._open_port(url, baudrate, port_factory, "u-blox unit")
        self.stats.extra.update(
            events=0, startups=0, ok=0, error_replies=0, echoes=0, payloads=0, other_urcs=0
        )
        self._closed = False

    # -- parsing -----------------------------------------------------------------

    def _bad_line(self, reason: str, line: bytes, why: str) -> None:
        # the start of a line may be a tag address: never put it in a message
        self._bad(reason, DataFormatError(f"{self.url}: line {self._line_no}: {why}"))

    def _event(self, text: str) -> tuple[int, float, float, int] | str:
        """(MAC, azimuth, RSSI, channel) of a ``+UUDF`` event, or why it is malformed."""
        fields = next(csv.reader([text[len("+UUDF:") :]]))
        if len(fields) not in FIELD_COUNTS:
            return f"+UUDF with {len(fields)} fields (expected 9, 10 or 12)"
        try:
            mac = mac_from_hex(fields[0])
            rssi1, azimuth, elevation, rssi2, channel = (int(f) for f in fields[1:6])
            int(fields[8])
            for extra in fields[9:]:
                int(extra)
        except ValueError:
            return "+UUDF with a non-numeric field"
        if not (-90 <= azimuth <= 90 and -90 <= elevation <= 90):
            return "+UUDF angle outside -90..90"
        if not 0 <= channel <= 39:
            return "+UUDF channel outside 0..39"
        if not all(RSSI_MIN_DBM <= r <= 0 for r in (rssi1, rssi2)):
            return f"+UUDF RSSI outside {RSSI_MIN_DBM}..0 dBm"
        # a reserved polarisation reads 0; a real RSSI is negative
        present = [r for r in (rssi1, rssi2) if r < 0]
        if not present:
            return "+UUDF without an RSSI"
        return mac, float(azimuth), float(max(present)), channel

    def _read_raw(self, timeout: float | None) -> BearingBatch | None:
        got_lines = self._read_lines()
        if got_lines is None:
            return None
        now = time.time_ns()
        lines, overflow = got_lines
        if overflow:
            lines.append(overflow)
        macs: list[int] = []
        az: list[float] = []
        rssi: list[float] = []
        chan: list[int] = []
        extra = self.stats.extra
        for raw in lines:
            self._line_no += 1
            line = raw.strip(b"\r \t")
            if not line:
                continue
            if not _TEXT.issuperset(line):
                self._binary_run += 1
                if self._binary_run >= BINARY_LINES:
                    raise SourceError(
                        f"{self.url}: the unit sends binary data, not +UUDF text lines; "
                        "switch its output to the AT text format (or check the baud rate)"
                    )
                self._bad_line("binary", line, "bytes that are not text")
                continue
            self._binary_run = 0
            if len(line) > MAX_LINE:
                self._bad_line("malformed", line, "line too long")
                continue
            text = line.decode("ascii")
            if text.startswith("+UUDF:"):
                got = self._event(text)
                if isinstance(got, str):
                    self._bad_line("malformed", line, got)
                    continue
                macs.append(got[0])
                az.append(got[1])
                rssi.append(got[2])
                chan.append(got[3])
            elif text.startswith("+UUDFP:"):
                extra["payloads"] += 1  # tag payload: not a bearing, not kept
            elif text.startswith("+STARTUP"):
                extra["startups"] += 1
            elif text == "OK":
                extra["ok"] += 1
            elif text == "ERROR":
                extra["error_replies"] += 1
            elif text.upper().startswith("AT"):
                extra["echoes"] += 1
            elif text.startswith("+"):
                extra["other_urcs"] += 1
            else:
                self._bad_line("malformed", line, "not an AT response or +UUDF event")
        if not macs:
            return None
        extra["events"] += len(macs)
        n = len(macs)
        t_ns = np.full(n, now, np.int64)
        try:
            emitter = self.hasher.hash_batch(np.asarray(macs, np.uint64), t_ns)
        except NonceUnavailableError:
            # a bearing is only useful now: without this epoch's nonce it is dropped
            self.stats.skip("no_nonce", count=n)
            return None
        relative = np.asarray(wrap_deg_180(self.sign * np.asarray(az)))
        sigma = [
            sigma_from_rssi(
                r, a, floor_deg=self.floor_deg, spacing_wavelengths=self.spacing_wavelengths
            )
            for r, a in zip(rssi, az, strict=True)
        ]
        return BearingBatch(
            sensor_id=self.sensor_id,
            t_ns=t_ns,
            azimuth_deg=np.asarray(wrap_deg_360(relative + self.boresight_deg)),
            sigma_deg=np.asarray(sigma),
            snr_db=np.asarray(rssi) - BLE_NOISE_FLOOR_DBM,
            channel=np.asarray(chan, np.int16),
            emitter=emitter,
            relative_deg=relative,
        )


__all__ = ["UbloxSource", "mac_from_hex", "sigma_from_rssi"]
