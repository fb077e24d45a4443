"""A software u-blox AoA anchor: ``+UUDF`` text on a pty or a TCP port, for tests and demos.

It prints ``+STARTUP`` on start, then for every tag one ``+UUDF`` event per
period with the firmware's field count (9, 10 or 12), the tag's azimuth plus
Gaussian noise rounded to whole degrees, and now and then a ``+UUDFP``
payload line. Faults on request: garbage lines, events cut short, and
binary output (what a unit left in binary mode sends). Tag addresses are
made-up example values given by the user; the emulator keeps nothing.
"""

from __future__ import annotations

import random
import time
from dataclasses import dataclass

from rfsas_hw.board.transport import EndpointServer, PtyEndpoint, TcpEndpoint
from rfsas_hw.errors import ConfigError
from rfsas_hw.sources.ublox import FIELD_COUNTS


@dataclass(frozen=True, slots=True)
class Tag:
    """A BLE tag the emulated anchor sees."""

    mac: str
    """12 hex digits."""
    azimuth_deg: float
    """True azimuth in the unit's convention, degrees, −90…90."""
    rssi_dbm: float = -60.0
    """RSSI of polarisation 1, dBm."""

    @classmethod
    def parse(cls, text: str) -> Tag:
        """``MAC,AZIMUTH[,RSSI]``, e.g. ``CCF9578E0D8A,20,-42``.

        Raises:
            ConfigError: malformed.
        """
        parts = text.split(",")
        try:
            mac = parts[0].replace(":", "").upper()
            int(mac, 16)
            if len(mac) != 12 or len(parts) not in (2, 3):
                raise ValueError("expected MAC,AZIMUTH[,RSSI]")
            az = float(parts[1])
            rssi = float(parts[2]) if len(parts) == 3 else -60.0
        except ValueError as err:
            raise ConfigError(f"tag {text!r}: {err} (expected MAC,AZIMUTH[,RSSI])") from err
        if not -90 <= az <= 90:
            raise ConfigError(f"tag {text!r}: azimuth outside -90..90")
        return cls(mac, az, rssi)


class UbloxEmulator:
    """Produces the anchor's output lines.

    Args:
        tags: tags in view.
        fields: field count of the emulated firmware (9, 10 or 12).
        noise_deg: one-sigma azimuth noise, degrees.
        garbage: probability per event of a garbage line or an event cut short.
        binary: send binary output instead of text.
        seed: random seed.

    Raises:
        ConfigError: a field count the firmware never had, or no tags.
    """

    def __init__(
        self,
        tags: list[Tag],
        *,
        fields: int = 10,
        noise_deg: float = 2.0,
        garbage: float = 0.0,
        binary: bool = False,
        seed: int = 0,
    ) -> None:
        if fields not in FIELD_COUNTS:
            raise ConfigError(f"+UUDF field count {fields}: firmware has 9, 10 or 12")
        if not tags:
            raise ConfigError("the emulated anchor needs at least one tag")
        self.tags = tags
        self.fields = fields
        self.noise_deg = noise_deg
        self.garbage = garbage
        self.binary = binary
        self._rng = random.Random(seed)
        self._t0 = time.monotonic()
        self.seq = 0
        self.events = 0
        self.garbage_lines = 0

    def startup(self) -> bytes:
        """What the anchor prints when it boots."""
        return b"\r\n+STARTUP\r\n"

    def event(self, tag: Tag) -> str:
        """One ``+UUDF`` line for ``tag`` (without line end)."""
        rng = self._rng
        az = max(-90, min(90, round(tag.azimuth_deg + rng.gauss(0.0, self.noise_deg))))
        el = round(rng.gauss(0.0, self.noise_deg))
        r1 = round(tag.rssi_dbm + rng.gauss(0.0, 1.0))
        r2 = round(tag.rssi_dbm - 1.0 + rng.gauss(0.0, 1.0))
        ms = int((time.monotonic() - self._t0) * 1000)
        parts = [tag.mac, str(r1), str(az), str(el), str(r2), str(37 + self.seq % 3)]
        parts += ['"ANCHOR000001"', '""', str(ms)]
        if self.fields >= 10:
            parts.append(str(self.seq % 65536))
        if self.fields == 12:
            parts += [str(az), str(el)]
        self.seq += 1
        return "+UUDF:" + ",".join(parts)

    def tick(self) -> bytes:
        """One period's output: an event per tag, maybe a payload line and faults."""
        if self.binary:
            return bytes(self._rng.randrange(256) for _ in range(48))
        out: list[str] = []
        for tag in self.tags:
            line = self.event(tag)
            self.events += 1
            if self._rng.random() < self.garbage:
                self.garbage_lines += 1
                cut = self._rng.randrange(8, len(line))
                line = line[:cut] if self._rng.random() < 0.5 else "#GARBAGE " + line[cut:]
            out.append(line)
            if self._rng.random() < 0.1:
                out.append(f"+UUDFP:{tag.mac},0201061AFF4C000215")
        return ("\r\n".join(out) + "\r\n").encode("ascii")


class UbloxServer(EndpointServer):
    """Serves an emulator on a pty or TCP port from a thread (or the caller's loop).

    Args:
        emulator: the anchor.
        endpoint: where the host connects.
        rate_hz: events per tag per second.
    """

    thread_name = "ublox-emulator"

    def __init__(
        self, emulator: UbloxEmulator, endpoint: PtyEndpoint | TcpEndpoint, rate_hz: float = 10.0
    ) -> None:
        if not rate_hz > 0:
            raise ConfigError(f"rate must be positive, got {rate_hz}")
        self.emulator = emulator
        self.endpoint = endpoint
        self.period_s = 1.0 / rate_hz
        self.bytes_sent = 0
        super().__init__()

    def run(self, duration_s: float | None = None) -> None:
        """Write the start-up line, then one tick per period until stopped."""
        start = time.monotonic()
        self.bytes_sent += self.endpoint.write(self.emulator.startup())
        next_t = start
        while not self.stop_event.is_set():
            now = time.monotonic()
            if duration_s is not None and now - start >= duration_s:
                break
            if now < next_t:
                self.stop_event.wait(min(next_t - now, 0.05))
                continue
            self.endpoint.read()  # drop what the host sends (AT commands)
            self.bytes_sent += self.endpoint.write(self.emulator.tick())
            next_t += self.period_s
            if next_t < now - 1.0:  # fell far behind: do not burst to catch up
                next_t = now + self.period_s
