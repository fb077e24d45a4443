"""``agrelo:URL`` — bearings from a Doppler DF unit in Agrelo format, with GPS position.

Doppler direction finders (Agrelo DFjr and compatibles) send one line per
bearing, ``%BBB/Q``: ``BBB`` the bearing in whole degrees clockwise from the
front of the antenna array (the vehicle's nose), ``Q`` a quality digit 0–9.
The same serial port (4800 baud, 8N1) usually carries the GPS receiver's
NMEA sentences; ``$GPRMC`` and ``$GPGGA`` (any talker: GP, GN, GL, …) give
the unit's position and, when moving, its course; every other sentence is
skipped.

**Quality → σ.** ``Q`` follows the APRS DF convention of a bearing wedge of
width ``W(Q) = 2^(9−Q)`` degrees (Q=9: 1°, Q=8: 2°, …, Q=1: 256°, about the
240° APRS uses). The wedge is read as ±2σ, so ``σ = max(W/4, min_sigma_deg)``.
``Q = 0`` means "no bearing" and the line is skipped.

**Azimuth.** The compass azimuth is ``heading + BBB``, where the heading is
``heading_deg`` for a fixed installation, or else the GPS course over ground
while the speed is at least ``min_speed_kn`` (the last good course is kept
while stopped). Without either, bearings are skipped (``no_heading``).

**Position.** Latitude/longitude become east/north metres of the local frame
whose origin is ``origin=(lat_deg, lon_deg)`` (the intersection centre),
through :class:`rfsas_hw.geo.SiteOrigin` (WGS-84, the same conversion every
other output uses).
Without an origin, :attr:`AgreloSource.pose` stays None and only
:attr:`AgreloSource.position_deg` is kept. A :class:`BearingBatch` has no
position column; the pose at each bearing's time is in :attr:`AgreloSource.track`.

Times are host UTC at the line's arrival. The unit does not identify the
transmitter: every bearing carries the configured ``emitter`` id and
``channel``.
"""

from __future__ import annotations

import math
import re
import time
from collections import deque
from typing import Any, ClassVar

import numpy as np

from rfsas_hw.angles import wrap_deg_180, wrap_deg_360
from rfsas_hw.errors import ConfigError, DataFormatError
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.records import BearingBatch, Pose
from rfsas_hw.sources.base import BatchFilter, ErrorPolicy
from rfsas_hw.sources.serial_lines import SerialLineSource
from rfsas_hw.sources.spec_options import SpecKeys

_BEARING = re.compile(rb"^%(\d{3})/(\d)$")
MAX_LINE = 200


def sigma_from_quality(q: int, min_sigma_deg: float = 2.0) -> float:
    """One-sigma bearing error for Agrelo/APRS quality digit ``q`` (1–9), degrees.

    Raises:
        ValueError: ``q`` outside 1–9.
    """
    if not 1 <= q <= 9:
        raise ValueError(f"quality {q} outside 1..9")
    return max(2.0 ** (9 - q) / 4.0, min_sigma_deg)


def nmea_checksum_ok(sentence: str) -> bool:
    """True when ``$...*hh`` carries a matching checksum (or none at all)."""
    body, star, given = sentence[1:].partition("*")
    if not star:
        return True
    calc = 0
    for ch in body:
        calc ^= ord(ch)
    try:
        return calc == int(given[:2], 16)
    except ValueError:
        return False


def _latlon(value: str, hemi: str, degree_digits: int) -> float:
    if not value:
        raise ValueError("empty coordinate")
    deg = float(value[:degree_digits])
    minutes = float(value[degree_digits:])
    out = deg + minutes / 60.0
    if hemi in ("S", "W"):
        out = -out
    elif hemi not in ("N", "E"):
        raise ValueError(f"hemisphere {hemi!r}")
    return out


def to_local_m(lat_deg: float, lon_deg: float, origin: tuple[float, float]) -> tuple[float, float]:
    """East/north metres of a position relative to ``origin`` (lat, lon), on the site plane."""
    east, north, _ = SiteOrigin(*origin).to_local(lat_deg, lon_deg)
    return float(east), float(north)


class AgreloSource(SerialLineSource):
    """Bearings from an Agrelo-format Doppler DF unit on a serial port.

    Args:
        url: device path or pyserial URL (``/dev/ttyUSB0``, ``socket://…``).
        baudrate: 4800 for most units.
        sensor_id: id of the bearings.
        origin: ``(lat_deg, lon_deg)`` of the local frame origin, or None.
        heading_deg: compass heading of the array's front for a fixed
            installation; None to use the GPS course.
        min_speed_kn: slowest speed at which the GPS course is trusted, knots.
        min_sigma_deg: floor of σ, degrees.
        channel: IEEE channel stamped on the bearings (the unit does not say).
        emitter: emitter id stamped on the bearings.
        port_factory: opens the port (default :func:`serial.serial_for_url`).

    Raises:
        SourceError: the port cannot be opened.
        ConfigError: a bad option.
    """

    scheme = "agrelo"
    device = "DF unit"
    max_line = MAX_LINE
    spec_keys: ClassVar[SpecKeys] = {
        "baud": ("baudrate", int),
        "origin": ("origin", str),
        "heading": ("heading_deg", float),
        "sensor_id": ("sensor_id", str),
        "channel": ("channel", int),
        "min_speed_kn": ("min_speed_kn", float),
    }
    """``agrelo:URL[#key=value&…]`` keys: baud, origin (LAT,LON), heading, sensor_id,
    channel, min_speed_kn."""
    yields_bearings = True

    def __init__(
        self,
        url: str,
        *,
        baudrate: int = 4800,
        sensor_id: str = "agrelo",
        origin: tuple[float, float] | str | None = None,
        heading_deg: float | None = None,
        min_speed_kn: float = 2.0,
        min_sigma_deg: float = 2.0,
        channel: int = 0,
        emitter: int = 0,
        port_factory: Any = None,
        errors: ErrorPolicy = "skip",
        filter: BatchFilter | None = None,
    ) -> None:
        super().__init__(errors=errors, filter=filter)
        self._closed = True
        if isinstance(origin, str):
            try:
                lat, lon = (float(v) for v in origin.split(","))
            except ValueError as err:
                raise ConfigError(f"origin {origin!r}: expected 'LAT,LON' in degrees") from err
            origin = (lat, lon)
        if origin is not None and not (-90 <= origin[0] <= 90 and -180 <= origin[1] <= 180):
            raise ConfigError(f"origin {origin} is not a latitude/longitude in degrees")
        self.sensor_id = sensor_id
        self.origin = origin
        self.fixed_heading_deg = heading_deg
        self.min_speed_kn = min_speed_kn
        self.min_sigma_deg = min_sigma_deg
        self.channel = channel
        self.emitter = emitter
        self.course_deg: float | None = None
        """Last trusted GPS course over ground, compass degrees."""
        self.position_deg: tuple[float, float] | None = None
        """Last GPS position (lat, lon), degrees."""
        self.track: deque[tuple[int, Pose]] = deque(maxlen=10_000)
        """(t_ns, pose) at each bearing, for bearings from a moving unit."""
        self._line_no = 0
        self._open_port(url, baudrate, port_factory, "serial port")
        self.stats.extra.update(nmea_fixes=0, nmea_skipped=0)
        self._closed = False

    @property
    def heading_deg(self) -> float | None:
        """The heading bearings are added to: fixed, or the GPS course."""
        return self.fixed_heading_deg if self.fixed_heading_deg is not None else self.course_deg

    # -- parsing -----------------------------------------------------------------

    def _bad_line(self, reason: str, line: bytes, why: str) -> None:
        text = line[:60].decode("ascii", "replace")
        self._bad(reason, DataFormatError(f"{self.url}: line {self._line_no}: {why}: {text!r}"))

    def _nmea(self, line: bytes) -> None:
        text = line.decode("ascii", "replace")
        if not nmea_checksum_ok(text):
            self._bad_line("nmea_checksum", line, "NMEA checksum mismatch")
            return
        fields = text.split("*", 1)[0].split(",")
        kind = fields[0][3:6] if len(fields[0]) == 6 else ""
        try:
            if kind == "RMC" and len(fields) >= 9:
                if fields[2] != "A":
                    return  # receiver warning: no valid fix
                lat = _latlon(fields[3], fields[4], 2)
                lon = _latlon(fields[5], fields[6], 3)
                speed = float(fields[7] or 0.0)
                if fields[8] and speed >= self.min_speed_kn:
                    self.course_deg = wrap_deg_360(float(fields[8]))
                self._fix(lat, lon)
            elif kind == "GGA" and len(fields) >= 7:
                if fields[6] in ("", "0"):
                    return  # no fix
                self._fix(_latlon(fields[2], fields[3], 2), _latlon(fields[4], fields[5], 3))
            else:
                self.stats.extra["nmea_skipped"] += 1
        except ValueError as err:
            self._bad_line("nmea_malformed", line, f"bad {kind} field ({err})")

    def _fix(self, lat: float, lon: float) -> None:
        self.position_deg = (lat, lon)
        self.stats.extra["nmea_fixes"] += 1

    @property
    def pose(self) -> Pose | None:
        """Last position in the local frame with the heading in use (None without
        ``origin`` or a fix)."""
        if self.origin is None or self.position_deg is None:
            return None
        east, north = to_local_m(*self.position_deg, self.origin)
        heading = self.heading_deg
        return Pose(east, north, math.nan if heading is None else heading)

    def _read_raw(self, timeout: float | None) -> BearingBatch | None:
        got_lines = self._read_lines()
        if got_lines is None:
            return None
        now = time.time_ns()
        lines, overflow = got_lines
        if overflow:
            self._line_no += 1
            self._bad_line("malformed", overflow, "line too long")
        rel: list[float] = []
        sig: list[float] = []
        for raw in lines:
            self._line_no += 1
            line = raw.strip(b"\r \t")
            if not line:
                continue
            if line.startswith(b"$"):
                self._nmea(line)
                continue
            m = _BEARING.match(line)
            if m is None:
                self._bad_line("malformed", line, "neither %BBB/Q nor NMEA")
                continue
            bearing, q = int(m.group(1)), int(m.group(2))
            if bearing >= 360:
                self._bad_line("malformed", line, f"bearing {bearing} ≥ 360")
                continue
            if q == 0:
                self.stats.skip("no_quality")
                continue
            if self.heading_deg is None:
                self.stats.skip("no_heading")
                continue
            rel.append(float(bearing))
            sig.append(sigma_from_quality(q, self.min_sigma_deg))
        if not rel:
            return None
        pose = self.pose
        if pose is not None:
            self.track.append((now, pose))
        relative = np.asarray(wrap_deg_180(np.asarray(rel)))
        heading = self.heading_deg
        assert heading is not None
        n = len(rel)
        return BearingBatch(
            sensor_id=self.sensor_id,
            t_ns=np.full(n, now, np.int64),
            azimuth_deg=np.asarray(wrap_deg_360(relative + heading)),
            sigma_deg=np.asarray(sig),
            snr_db=np.full(n, np.nan),
            channel=np.full(n, self.channel, np.int16),
            emitter=np.full(n, self.emitter, np.uint64),
            relative_deg=relative,
        )


__all__ = ["AgreloSource", "nmea_checksum_ok", "sigma_from_quality", "to_local_m"]
