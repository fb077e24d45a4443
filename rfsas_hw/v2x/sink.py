"""Live CPMs from the backend: a result sink sending each step's messages.

URLs (``rfsas backend --cpm URL``)::

    udp://HOST:PORT              the bare CPM in each datagram
    udp://HOST:PORT?btp=1        a BTP-B header (port 2009) before the CPM, as the
                                 UDP bridges of ``etsi_its_messages`` and Vanetza's
                                 socktap-style tools take it
    mqtt://HOST[:PORT]/TOPIC     published on TOPIC (default ``its/cpm``), QoS 0;
    mqtts://HOST[:PORT]/TOPIC?ca=…&cert=…&key=…   the same with mutual TLS

Other UDP options (``iface``, ``ttl``) and MQTT options are the link's
(:mod:`rfsas_hw.link.transport`, :mod:`rfsas_hw.link.mqtt`). The sink never holds
the backend up: a message that cannot be sent is counted in
:attr:`CpmSink.dropped`, not retried.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from urllib.parse import parse_qs, urlencode, urlsplit, urlunsplit

from rfsas_hw.backend.site import SiteConfig
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.errors import ConfigError, CpmFormatError, LinkError
from rfsas_hw.link.topics import Route
from rfsas_hw.link.transport import Transport, open_transport
from rfsas_hw.records import Assessment, BearingBatch, Fix, Pose
from rfsas_hw.v2x.geonet import btp_b
from rfsas_hw.v2x.perception import CpmConfig, CpmGenerator

log = logging.getLogger(__name__)

__all__ = ["DEFAULT_TOPIC", "CpmSender", "CpmSink", "backend_cpm_sink"]

DEFAULT_TOPIC = "its/cpm"
"""MQTT topic of CPMs when the URL names none."""


class CpmSender:
    """Sends encoded CPMs to one URL (see the module docstring).

    Raises:
        ConfigError: a URL that is neither ``udp://`` nor ``mqtt(s)://``, or a bad ``btp``.
        LinkError: the socket or the broker connection cannot be opened.
    """

    def __init__(self, url: str) -> None:
        parts = urlsplit(url)
        query = parse_qs(parts.query, keep_blank_values=True)
        self.url = url
        self.btp = False
        self.topic: str | None = None
        if parts.scheme == "udp":
            btp = query.pop("btp", ["0"])[-1]
            if btp not in ("0", "1"):
                raise ConfigError(f"CPM URL {url!r}: btp must be 0 or 1, got {btp!r}")
            self.btp = btp == "1"
            inner = urlunsplit(parts._replace(query=urlencode(query, doseq=True)))
        elif parts.scheme in ("mqtt", "mqtts"):
            self.topic = parts.path.strip("/") or DEFAULT_TOPIC
            if any(c in self.topic for c in "+#\0"):
                raise ConfigError(f"CPM URL {url!r}: topic {self.topic!r} has a wildcard")
            inner = urlunsplit(parts._replace(path=""))
        else:
            raise ConfigError(
                f"CPM URL {url!r}: expected udp://HOST:PORT[?btp=1] or mqtt(s)://HOST[:PORT]/TOPIC"
            )
        self._transport: Transport | None = open_transport(inner, "send")
        self.sent = 0
        """Messages sent."""
        self.dropped = 0
        """Messages that could not be sent."""

    def send(self, cpm: bytes) -> bool:
        """Send one encoded CPM; True if it went out."""
        transport = self._transport
        if transport is None:
            self.dropped += 1
            return False
        try:
            if self.topic is not None:
                transport.publish(Route(self.topic), cpm)  # type: ignore[attr-defined]
            else:
                transport.send(btp_b(cpm) if self.btp else cpm)
        except (OSError, LinkError) as err:
            self.dropped += 1
            log.warning("CPM: cannot send to %s: %s", self.url, err)
            return False
        self.sent += 1
        return True

    def close(self) -> None:
        """Close the socket or broker connection; idempotent."""
        if self._transport is not None:
            self._transport.close()
            self._transport = None


class CpmSink:
    """A backend result sink: each step's tracks as CPMs, sent by a :class:`CpmSender`.

    It learns the units' poses from the bearings it is shown (``on_bearings``), so
    that the sensor information container describes the units heard.

    Args:
        config: the station and generation settings.
        sender: where the messages go (closed with the sink).
        vehicle: returns the current vehicle state (a ``vehicle`` station's reference).
        clock: UTC ns, the reference time of a step without assessments.
    """

    def __init__(
        self,
        config: CpmConfig,
        sender: CpmSender,
        *,
        vehicle: Callable[[], VehicleState | None] | None = None,
        clock: Callable[[], int] = time.time_ns,
    ) -> None:
        self.generator = CpmGenerator(config)
        self.sender = sender
        self.vehicle = vehicle
        self.clock = clock
        self.stations: dict[str, Pose] = {}
        """Latest pose of every unit heard, by sensor id."""
        self.errors = 0
        """Steps whose messages could not be generated (logged)."""

    @classmethod
    def to_url(
        cls,
        url: str,
        config: CpmConfig,
        *,
        vehicle: Callable[[], VehicleState | None] | None = None,
        clock: Callable[[], int] = time.time_ns,
    ) -> CpmSink:
        """A sink sending to ``url`` (see the module docstring).

        Raises:
            ConfigError: a bad URL.
            LinkError: the socket or broker connection cannot be opened.
        """
        return cls(config, CpmSender(url), vehicle=vehicle, clock=clock)

    def on_bearings(self, bearings: BearingBatch, pose: Pose) -> None:
        """Remember the pose of the unit that measured ``bearings``."""
        self.stations[bearings.sensor_id] = pose

    def on_results(self, fixes: Sequence[Fix], assessments: Sequence[Assessment]) -> None:
        """Generate and send this step's CPMs (often none; see :mod:`rfsas_hw.v2x.perception`)."""
        now = max((a.t_ns for a in assessments), default=None)
        if now is None:
            now = self.clock()
        vehicle = self.vehicle() if self.vehicle is not None else None
        try:
            messages = self.generator.step(now, assessments, self.stations, vehicle)
        except (ConfigError, CpmFormatError) as err:
            self.errors += 1
            log.warning("CPM: step at %d ns not sent: %s", now, err)
            return
        for message in messages:
            self.sender.send(message.data)

    def counters(self) -> dict[str, int]:
        """Messages generated, sent, dropped, and steps that failed."""
        return {
            "cpm.generated": self.generator.generated,
            "cpm.sent": self.sender.sent,
            "cpm.dropped": self.sender.dropped,
            "cpm.errors": self.errors,
        }

    def close(self) -> None:
        """Close the sender; idempotent."""
        self.sender.close()


def backend_cpm_sink(
    url: str, station_id: int, site: SiteConfig, *, vehicle_station: bool = False
) -> CpmSink:
    """The CPM sink of a backend: station ``station_id``, a roadside unit at the site
    origin (or, with ``vehicle_station``, a vehicle: set :attr:`CpmSink.vehicle`), each
    unit's field of view as the site declares it.

    Raises:
        ConfigError: the site has no origin, or a bad URL.
        LinkError: the socket or broker connection cannot be opened.
    """
    if site.origin is None:
        raise ConfigError("--cpm needs the site origin: --origin LAT,LON or site.origin")
    config = CpmConfig(
        station_id=station_id,
        origin=site.origin,
        station="vehicle" if vehicle_station else "rsu",
        fov_deg={s.id: s.fov_deg for s in site.sensors},
    )
    return CpmSink.to_url(url, config)
