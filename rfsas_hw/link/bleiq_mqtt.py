"""``bleiq+mqtt://HOST[:PORT][/FILTER]?elements=N``: IQ reports a Silicon Labs AoA locator
host publishes to an MQTT broker.

The host publishes each report of its locator board on
``silabs/aoa/iq_report/<locator id>/<tag id>`` (:mod:`rfsas_hw.sources.ble_iq_silabs`).
This source subscribes to ``FILTER`` (default ``silabs/aoa/iq_report/+/+``;
name the locator, ``silabs/aoa/iq_report/ble-pd-0C4314F4634A/+``, when the
broker serves several) and turns every report into an array observation
stamped with the time it arrived (UTC ns, this host's clock). A source is one
array: under a wildcard, the first locator heard is the one read, and
reports of others are counted (``other_locator``), not used.

Options: ``elements`` (required), ``pattern`` (the locator's switching
pattern as antenna ids 0…N−1; default 0…N−1), ``slot`` (1 or 2 µs, as the
locator was set; the host's default is 1), ``connect_s`` (how long opening
waits for the broker, default 5 s), ``queue`` (messages held between reads,
default 65536; the oldest go first when it is full).

The MQTT client is the package's own (:mod:`rfsas_hw.link.mqtt`; this source lives in
the link package because it reads through it):
it reconnects with backoff after a lost broker and bounds its queue. Plain
MQTT only; run the source next to the broker or tunnel it.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from rfsas_hw.errors import CaptureFormatError, LinkError, SourceError
from rfsas_hw.link.mqtt import MqttEndpoint, MqttTransport
from rfsas_hw.records import ObservationBatch
from rfsas_hw.sources.base import Source
from rfsas_hw.sources.ble_iq import ble_channel_mhz
from rfsas_hw.sources.ble_iq_silabs import TOPIC_PREFIX, parse_message
from rfsas_hw.sources.ble_iq_source import IqReportSource, IqRow, parse_query

DEFAULT_FILTER = f"{TOPIC_PREFIX}/+/+"
DEFAULT_PORT = 1883
READ_SLICE_S = 0.5
"""How long a read without a timeout waits for messages, seconds."""


def split_address(what: str, name: str) -> tuple[str, int, str]:
    """(host, port, topic filter) of ``//HOST[:PORT][/FILTER]``.

    Raises:
        SourceError: no ``//HOST``, or a bad port.
    """
    if not what.startswith("//") or len(what) == 2:
        raise SourceError(f"{name}: //HOST[:PORT][/FILTER] expected")
    netloc, _, flt = what[2:].partition("/")
    host, sep, port_text = netloc.rpartition(":")
    if not sep:
        host, port_text = netloc, str(DEFAULT_PORT)
    try:
        port = int(port_text)
    except ValueError as err:
        raise SourceError(f"{name}: port {port_text!r} is not a number") from err
    if not host or not 1 <= port <= 65535:
        raise SourceError(f"{name}: a broker host and a port 1…65535 expected")
    return host.strip("[]"), port, flt or DEFAULT_FILTER


class BleIqMqttSource(IqReportSource):
    """IQ reports of a Silicon Labs locator, from its host's MQTT messages.

    Args:
        what: ``//HOST[:PORT][/FILTER]``.
        elements, pattern, errors, filter: see
            :class:`~rfsas_hw.sources.ble_iq_source.IqReportSource`.
        slot_us: the locator's slot duration, µs (1 or 2).
        connect_s: how long to wait for the broker, s.
        queue: most messages held between reads.
        clock: UTC ns, for the reports' times.

    Raises:
        SourceError: a bad option, or no broker within ``connect_s``.
    """

    scheme = "bleiq+mqtt"

    def __init__(
        self,
        what: str,
        *,
        elements: int,
        pattern: list[int] | None = None,
        slot_us: int = 1,
        connect_s: int = 5,
        queue: int = 65_536,
        clock: Callable[[], int] = time.time_ns,
        **base: Any,
    ) -> None:
        name = f"{self.scheme}:{what}"
        host, port, flt = split_address(what, name)
        if slot_us not in (1, 2):
            raise SourceError(f"{name}: slot {slot_us}: 1 or 2 (µs) expected")
        if not 1 <= connect_s <= 3600 or not 1 <= queue <= 10_000_000:
            raise SourceError(f"{name}: connect_s 1…3600 and queue 1…10000000 expected")
        super().__init__(name, elements=elements, pattern=pattern, **base)
        self.what = what
        self.topic_filter = flt
        self.slot_us = slot_us
        self.clock = clock
        self.locator: str | None = None
        """The locator this source reads (the first heard)."""
        endpoint = MqttEndpoint(
            host, port, subscriptions=(flt,), connect_s=float(connect_s), queue=queue
        )
        try:
            self._mqtt = MqttTransport(endpoint, "recv")
        except LinkError as err:
            self.close()
            raise SourceError(f"{name}: {err}") from err

    @classmethod
    def from_spec(cls, arg: str, **options: Any) -> Source[Any]:
        """``//HOST[:PORT][/FILTER]?elements=N&pattern=…&slot=1&connect_s=5&queue=…``;
        keywords win.

        Raises:
            SourceError: a missing, malformed or unknown option, or no broker.
        """
        keys = {"elements": "elements", "pattern": "pattern", "slot": "slot_us"}
        what, options = parse_query(
            cls.scheme, arg, options, {**keys, "connect_s": "connect_s", "queue": "queue"}
        )
        return cls(what, **options)

    def __repr__(self) -> str:
        return f"BleIqMqttSource({self.what!r})"

    def _read_raw(self, timeout: float | None) -> ObservationBatch | None:
        messages = self._mqtt.recv_many(READ_SLICE_S if timeout is None else timeout)
        if not messages:
            return None
        t_ns = self.clock()
        rows: list[IqRow] = []
        for payload, topic in messages:
            try:
                msg = parse_message(topic or "", payload, self.slot_us)
            except CaptureFormatError as err:
                self._bad("bad_report", err)
                continue
            if self.locator is None:
                self.locator = msg.locator
            if msg.locator != self.locator:
                self.stats.skip("other_locator")
                continue
            freq = ble_channel_mhz(msg.report.channel_index)
            where = f"report {msg.report.event_counter} from locator {msg.locator[:80]}"
            rows.append(IqRow(t_ns, msg.key, freq, msg.report, where))
        mq = self._mqtt.stats
        self.stats.extra.update(
            iq_reports=self.stats.extra.get("iq_reports", 0) + len(rows),
            mqtt_received=mq.received,
            mqtt_dropped=mq.dropped,
            mqtt_disconnects=mq.disconnects,
        )
        return self._batch(rows)

    def _close(self) -> None:
        mqtt = getattr(self, "_mqtt", None)
        if mqtt is not None:
            mqtt.close(flush_s=0.0)
