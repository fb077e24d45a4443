"""The IQ reports Silicon Labs' AoA locator host publishes over MQTT.

The locator host of the Gecko SDK (``app/bluetooth/example_host/bt_aoa_host_locator``,
its ``aoa_util`` and ``aoa_cte`` modules) publishes, in its IQ-report mode,
one message per report the locator board's controller gives:

- topic ``silabs/aoa/iq_report/<locator id>/<tag id>``; an id is
  ``ble-pd-`` (public device address) or ``ble-sr-`` (static random) and the
  12 hex digits of the address, most significant octet first;
- payload, a JSON object written by cJSON's formatted printer::

      {
        "channel":	17,
        "rssi":	-60,
        "sequence":	42,
        "samples":	[12, -7, 11, -9, …]
      }

  ``channel`` the BLE channel index, ``rssi`` whole dBm (a signed octet),
  ``sequence`` the periodic-advertising or connection event counter, and
  ``samples`` the report's IQ samples as signed octets, I and Q interleaved
  (``I0, Q0, I1, Q1, …``).

The samples follow the Core specification's timing, as the host's own angle
code reads them: 8 reference samples 1 µs apart on the pattern's first
antenna, then one sample per sample slot (``2·slot`` µs apart) on the
antennas of the switching pattern in turn from its second entry; the host
treats the 8th reference sample as the first antenna's sample of the first
snapshot. The JSON does not carry the slot duration (the host's default is
1 µs) or the switching pattern: they are options of the source. A value of
``-128`` is taken as a sample clipped at the octet's rail and not used.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass

import numpy as np

from rfsas_hw.errors import CaptureFormatError
from rfsas_hw.sources.ble_iq import REFERENCE_SAMPLES, SENTINEL_8, IqReport

TOPIC_PREFIX = "silabs/aoa/iq_report"
MAX_PAYLOAD = 16_384
"""Largest payload read, bytes (a report of 127 samples is under 1.3 kB)."""
MAX_PAIRS = 127
"""Most (I, Q) pairs a report may hold (the host keeps the length in one octet)."""
_ID = re.compile(r"ble-(?P<type>pd|sr)-(?P<hex>[0-9A-Fa-f]{12})")


def address_id(address: int, random: bool = True) -> str:
    """The host's id of a BLE address: ``ble-sr-`` or ``ble-pd-`` and 12 hex digits."""
    return f"ble-{'sr' if random else 'pd'}-{address:012X}"


def id_key(tag_id: str) -> int:
    """The address a ``ble-pd-…`` / ``ble-sr-…`` id holds, as a 48-bit integer.

    Raises:
        ValueError: not such an id.
    """
    m = _ID.fullmatch(tag_id)
    if m is None:
        raise ValueError(f"{tag_id!r} is not a ble-pd-/ble-sr- id")
    return int(m["hex"], 16)


def report_topic(locator_id: str, tag_id: str) -> str:
    """``silabs/aoa/iq_report/<locator_id>/<tag_id>``."""
    return f"{TOPIC_PREFIX}/{locator_id}/{tag_id}"


def split_topic(topic: str) -> tuple[str, str]:
    """(locator id, tag id) of an IQ report topic.

    Raises:
        CaptureFormatError: not ``silabs/aoa/iq_report/<locator>/<tag>``.
    """
    head, _, rest = topic.rpartition("/")
    prefix, _, locator = head.rpartition("/")
    if prefix != TOPIC_PREFIX or not locator or not rest:
        # the topic is not echoed: its last level may be a device address
        raise CaptureFormatError(
            f"a topic of {topic.count('/') + 1} levels that is not {TOPIC_PREFIX}/<locator>/<tag>"
        )
    return locator, rest


def _integer(obj: dict[str, object], name: str, low: int, high: int, where: str) -> int:
    value = obj.get(name)
    if isinstance(value, bool) or not isinstance(value, int):
        raise CaptureFormatError(f"{where}: {name!r} must be a whole number, got {value!r:.40}")
    if not low <= value <= high:
        raise CaptureFormatError(f"{where}: {name} {value} outside {low}…{high}")
    return value


def parse_iq_json(payload: bytes, where: str, slot_us: int = 1) -> IqReport:
    """Decode one payload; ``slot_us`` is the slot duration the locator was set to.

    Raises:
        CaptureFormatError: not JSON, not an object, a field missing or of the wrong
            type or range, an odd number of sample values, fewer samples than a
            reference period and one slot, more than :data:`MAX_PAIRS` (``where``
            and the field named).
    """
    if len(payload) > MAX_PAYLOAD:
        raise CaptureFormatError(
            f"{where}: payload of {len(payload)} bytes (at most {MAX_PAYLOAD})"
        )
    try:
        obj = json.loads(payload)
    except (ValueError, RecursionError) as err:  # UnicodeDecodeError is a ValueError
        raise CaptureFormatError(f"{where}: not JSON: {err}") from err
    if not isinstance(obj, dict):
        raise CaptureFormatError(f"{where}: a JSON object expected, got {type(obj).__name__}")
    channel = _integer(obj, "channel", 0, 39, where)
    rssi = _integer(obj, "rssi", -128, 127, where)
    sequence = _integer(obj, "sequence", 0, 65535, where)
    samples = obj.get("samples")
    if not isinstance(samples, list):
        raise CaptureFormatError(f"{where}: 'samples' must be a list of numbers")
    if any(isinstance(v, bool) or not isinstance(v, int) or not -128 <= v <= 127 for v in samples):
        raise CaptureFormatError(f"{where}: 'samples' must be whole numbers in -128…127")
    if len(samples) % 2:
        raise CaptureFormatError(f"{where}: {len(samples)} sample values: I and Q pairs expected")
    pairs = len(samples) // 2
    if not REFERENCE_SAMPLES + 1 <= pairs <= MAX_PAIRS:
        raise CaptureFormatError(
            f"{where}: {pairs} samples: {REFERENCE_SAMPLES + 1}…{MAX_PAIRS} expected"
        )
    raw = np.array(samples, np.float64)
    i, q = raw[0::2], raw[1::2]
    iq = i + 1j * q
    iq[(i == SENTINEL_8) | (q == SENTINEL_8)] = np.nan
    return IqReport("connectionless", 0, channel, 1, float(rssi), 0, 0, slot_us, 0, sequence, iq)


def encode_iq_json(report: IqReport) -> bytes:
    """The payload the host publishes for ``report`` (cJSON's formatted layout; RSSI
    rounded to whole dBm; NaN samples written as -128).

    Raises:
        ValueError: a sample outside -127…127 or more than :data:`MAX_PAIRS` samples.
    """
    if len(report.iq) > MAX_PAIRS:
        raise ValueError(f"{len(report.iq)} samples; the host carries at most {MAX_PAIRS}")
    values: list[int] = []
    for v in report.iq:
        i, q = (round(v.real), round(v.imag)) if np.isfinite(v) else (SENTINEL_8, SENTINEL_8)
        if np.isfinite(v) and (abs(i) > 127 or abs(q) > 127):
            raise ValueError("IQ samples must fit a signed octet (−127…127)")
        values += [int(i), int(q)]
    text = (
        "{\n"
        f'\t"channel":\t{report.channel_index},\n'
        f'\t"rssi":\t{round(report.rssi_dbm)},\n'
        f'\t"sequence":\t{report.event_counter},\n'
        f'\t"samples":\t[{", ".join(map(str, values))}]\n'
        "}"
    )
    return text.encode()


@dataclass(frozen=True, slots=True)
class SilabsMessage:
    """One decoded MQTT message."""

    locator: str
    tag: str
    key: int
    """The tag's address as a 48-bit integer."""
    report: IqReport


def parse_message(topic: str, payload: bytes, slot_us: int = 1) -> SilabsMessage:
    """Decode the topic and payload of one IQ report message.

    Messages name the locator, never the tag (its id holds the tag's address).

    Raises:
        CaptureFormatError: a topic that is not an IQ report's, a tag id that is not
            an address id, or a bad payload (see :func:`parse_iq_json`).
    """
    locator, tag = split_topic(topic)
    where = f"report from locator {locator[:80]}"  # not the tag id: it holds an address
    try:
        key = id_key(tag)
    except ValueError as err:
        raise CaptureFormatError(f"{where}: the tag id is not a ble-pd-/ble-sr- id") from err
    return SilabsMessage(locator, tag, key, parse_iq_json(payload, where, slot_us))
