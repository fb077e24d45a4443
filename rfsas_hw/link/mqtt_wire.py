"""MQTT 5.0 packets: the subset a link client needs, encoded and parsed.

Client → broker: CONNECT, PUBLISH (QoS 0 or 1, retain, Message Expiry
Interval), PUBACK, SUBSCRIBE, PINGREQ, DISCONNECT. Broker → client: CONNACK,
PUBLISH, PUBACK, SUBACK, PINGRESP, DISCONNECT. Layouts follow the OASIS MQTT
Version 5.0 standard (section 2 for the fixed header, variable byte integers
and properties; section 3 for each packet).

:class:`PacketReader` takes bytes as they arrive and returns the complete
packets; it holds at most one partial packet. Anything malformed raises
:class:`MqttProtocolError` (the connection is then useless and is dropped).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

from rfsas_hw.errors import LinkError

CONNECT = 1
CONNACK = 2
PUBLISH = 3
PUBACK = 4
SUBSCRIBE = 8
SUBACK = 9
PINGREQ = 12
PINGRESP = 13
DISCONNECT = 14
AUTH = 15

MAX_PACKET = 1 << 20
"""Largest packet accepted from a broker, bytes (link datagrams are ≤ 1472)."""

PINGREQ_PACKET = b"\xc0\x00"
DISCONNECT_PACKET = b"\xe0\x00"

PROP_MESSAGE_EXPIRY = 0x02
PROP_SERVER_KEEP_ALIVE = 0x13
PROP_REASON_STRING = 0x1F
PROP_RECEIVE_MAXIMUM = 0x21

# property id → value kind: b byte, h two-byte int, i four-byte int, v variable
# byte integer, s UTF-8 string, d binary data, p UTF-8 string pair (standard 2.2.2.2)
_PROPERTY_KINDS = {
    0x01: "b",
    0x02: "i",
    0x03: "s",
    0x08: "s",
    0x09: "d",
    0x0B: "v",
    0x11: "i",
    0x12: "s",
    0x13: "h",
    0x15: "s",
    0x16: "d",
    0x17: "b",
    0x18: "i",
    0x19: "b",
    0x1A: "s",
    0x1C: "s",
    0x1F: "s",
    0x21: "h",
    0x22: "h",
    0x23: "h",
    0x24: "b",
    0x25: "b",
    0x26: "p",
    0x27: "i",
    0x28: "b",
    0x29: "b",
    0x2A: "b",
}

REASONS = {
    0x00: "success",
    0x80: "unspecified error",
    0x81: "malformed packet",
    0x82: "protocol error",
    0x83: "implementation specific error",
    0x84: "unsupported protocol version",
    0x85: "client identifier not valid",
    0x86: "bad user name or password",
    0x87: "not authorized",
    0x88: "server unavailable",
    0x89: "server busy",
    0x8A: "banned",
    0x8B: "server shutting down",
    0x8C: "bad authentication method",
    0x8D: "keep alive timeout",
    0x8E: "session taken over",
    0x8F: "topic filter invalid",
    0x90: "topic name invalid",
    0x91: "packet identifier in use",
    0x93: "receive maximum exceeded",
    0x95: "packet too large",
    0x97: "quota exceeded",
    0x99: "payload format invalid",
    0x9A: "retain not supported",
    0x9B: "QoS not supported",
    0x9C: "use another server",
    0x9D: "server moved",
    0x9E: "shared subscriptions not supported",
    0x9F: "connection rate exceeded",
    0xA0: "maximum connect time",
    0xA1: "subscription identifiers not supported",
    0xA2: "wildcard subscriptions not supported",
}

_U16 = struct.Struct(">H")
_U32 = struct.Struct(">I")


class MqttProtocolError(LinkError):
    """A broker sent bytes that are not a well-formed MQTT 5 packet."""


def reason_text(code: int) -> str:
    """The standard's name of a reason code, e.g. ``not authorized (0x87)``."""
    return f"{REASONS.get(code, 'reason')} ({code:#04x})"


def varint(value: int) -> bytes:
    """A variable byte integer (standard 1.5.5), 0 ≤ value < 2**28.

    Raises:
        ValueError: the value is out of range.
    """
    if not 0 <= value < 1 << 28:
        raise ValueError(f"{value} does not fit a variable byte integer")
    out = bytearray()
    while True:
        value, digit = value >> 7, value & 0x7F
        out.append(digit | (0x80 if value else 0))
        if not value:
            return bytes(out)


def utf8(text: str) -> bytes:
    """A UTF-8 encoded string with its two-byte length (standard 1.5.4).

    Raises:
        ValueError: longer than 65,535 bytes.
    """
    raw = text.encode("utf-8")
    if len(raw) > 0xFFFF:
        raise ValueError(f"string of {len(raw)} bytes is too long for MQTT")
    return _U16.pack(len(raw)) + raw


def _packet(first: int, body: bytes) -> bytes:
    return bytes((first,)) + varint(len(body)) + body


def connect_packet(client_id: str, keepalive_s: int, clean_start: bool = True) -> bytes:
    """CONNECT without user name or password (the TLS certificate names the client).

    Raises:
        ValueError: a keepalive outside 0…65,535 s or an overlong client id.
    """
    if not 0 <= keepalive_s <= 0xFFFF:
        raise ValueError(f"keepalive {keepalive_s} s is outside 0…65535")
    flags = 0x02 if clean_start else 0x00
    body = b"\x00\x04MQTT\x05" + bytes((flags,)) + _U16.pack(keepalive_s) + b"\x00"
    return _packet(CONNECT << 4, body + utf8(client_id))


def publish_packet(
    topic: str,
    payload: bytes,
    *,
    qos: int = 0,
    retain: bool = False,
    packet_id: int = 0,
    expiry_s: int | None = None,
) -> bytes:
    """PUBLISH of ``payload`` on ``topic``; QoS 1 needs a ``packet_id`` (1…65,535).

    Raises:
        ValueError: QoS other than 0 or 1, a missing packet id, or an expiry
            outside 0…2**32 − 1 s.
    """
    first, head = publish_head(
        topic, qos=qos, retain=retain, packet_id=packet_id, expiry_s=expiry_s
    )
    return framed(first, head, payload)


def publish_head(
    topic: str,
    *,
    qos: int = 0,
    retain: bool = False,
    packet_id: int = 0,
    expiry_s: int | None = None,
) -> tuple[int, bytes]:
    """The first byte and the variable header (topic, packet id, properties) of a
    PUBLISH: the same for every message a sender publishes on one topic at QoS 0, so it
    can be made once (:func:`framed` adds the payload).

    Raises:
        ValueError: as :func:`publish_packet`.
    """
    if qos not in (0, 1):
        raise ValueError(f"QoS {qos} is not supported (0 or 1)")
    first = (PUBLISH << 4) | (qos << 1) | (1 if retain else 0)
    head = utf8(topic)
    if qos:
        if not 0 < packet_id <= 0xFFFF:
            raise ValueError(f"packet id {packet_id} outside 1…65535")
        head += _U16.pack(packet_id)
    if expiry_s is None:
        head += b"\x00"
    else:
        if not 0 <= expiry_s <= 0xFFFFFFFF:
            raise ValueError(f"message expiry {expiry_s} s out of range")
        head += b"\x05" + bytes((PROP_MESSAGE_EXPIRY,)) + _U32.pack(expiry_s)
    return first, head


def framed(first: int, head: bytes, payload: bytes) -> bytes:
    """A whole packet: its first byte, remaining length, ``head`` and ``payload``.

    Raises:
        ValueError: longer than a packet can be (2**28 − 1 bytes after the fixed header).
    """
    return b"".join((bytes((first,)), varint(len(head) + len(payload)), head, payload))


def puback_packet(packet_id: int) -> bytes:
    """PUBACK with reason success (the short form of standard 3.4.2.1)."""
    return b"\x40\x02" + _U16.pack(packet_id)


def subscribe_packet(packet_id: int, filters: list[tuple[str, int]]) -> bytes:
    """SUBSCRIBE to ``(topic filter, maximum QoS)`` pairs.

    Raises:
        ValueError: no filter, or a packet id outside 1…65,535.
    """
    if not filters:
        raise ValueError("SUBSCRIBE needs at least one topic filter")
    if not 0 < packet_id <= 0xFFFF:
        raise ValueError(f"packet id {packet_id} outside 1…65535")
    body = _U16.pack(packet_id) + b"\x00"
    for topic_filter, qos in filters:
        body += utf8(topic_filter) + bytes((qos & 0x03,))
    return _packet((SUBSCRIBE << 4) | 0x02, body)


@dataclass(frozen=True, slots=True)
class Publish:
    """A PUBLISH from the broker."""

    topic: str
    payload: bytes
    qos: int = 0
    retain: bool = False
    packet_id: int = 0


@dataclass(frozen=True, slots=True)
class Ack:
    """CONNACK, PUBACK, SUBACK or DISCONNECT from the broker."""

    kind: int
    """Packet type (:data:`CONNACK`, :data:`PUBACK`, :data:`SUBACK`, :data:`DISCONNECT`)."""
    packet_id: int = 0
    """Packet identifier (PUBACK, SUBACK)."""
    reasons: tuple[int, ...] = (0,)
    """Reason code(s): one, or one per topic filter of a SUBACK."""
    properties: dict[int, object] = field(default_factory=dict)
    """Properties by identifier (string pairs collected in a list)."""

    @property
    def failed(self) -> bool:
        """True when a reason code is a failure (0x80 or above)."""
        return any(code >= 0x80 for code in self.reasons)


@dataclass(frozen=True, slots=True)
class Ping:
    """PINGRESP."""


Packet = Publish | Ack | Ping


def _varint_at(buf: bytes | bytearray | memoryview, at: int, end: int) -> tuple[int, int]:
    """(value, next offset) of the variable byte integer at ``at``; (-1, at) when
    the bytes up to ``end`` do not hold all of it yet.

    Raises:
        MqttProtocolError: more than four bytes.
    """
    value = 0
    shift = 0
    for i in range(at, min(at + 4, end)):
        byte = buf[i]
        value |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return value, i + 1
        shift += 7
    if end - at >= 4:
        raise MqttProtocolError(f"variable byte integer at offset {at} runs past four bytes")
    return -1, at


def parse_properties(body: bytes, at: int) -> tuple[dict[int, object], int]:
    """The properties starting at ``at`` (length first) and the offset after them.

    Raises:
        MqttProtocolError: an unknown property or one that runs past the packet.
    """
    length, at = _varint_at(body, at, len(body))
    if length < 0 or at + length > len(body):
        raise MqttProtocolError("properties run past the end of the packet")
    end = at + length
    props: dict[int, object] = {}
    try:
        while at < end:
            pid = body[at]
            kind = _PROPERTY_KINDS.get(pid)
            at += 1
            value: object
            if kind == "b":
                value, at = body[at], at + 1
            elif kind == "h":
                value, at = _U16.unpack_from(body, at)[0], at + 2
            elif kind == "i":
                value, at = _U32.unpack_from(body, at)[0], at + 4
            elif kind == "v":
                value, at = _varint_at(body, at, end)
            elif kind in ("s", "d"):
                n = _U16.unpack_from(body, at)[0]
                raw, at = body[at + 2 : at + 2 + n], at + 2 + n
                value = raw.decode("utf-8", "replace") if kind == "s" else bytes(raw)
            elif kind == "p":
                pair = []
                for _ in range(2):
                    n = _U16.unpack_from(body, at)[0]
                    pair.append(body[at + 2 : at + 2 + n].decode("utf-8", "replace"))
                    at += 2 + n
                listed = props.setdefault(pid, [])
                assert isinstance(listed, list)
                listed.append(tuple(pair))
                continue
            else:
                raise MqttProtocolError(f"unknown property {pid:#04x}")
            props[pid] = value
    except struct.error as err:
        raise MqttProtocolError(f"property runs past the end of the packet: {err}") from None
    if at != end:
        raise MqttProtocolError("a property runs past the properties' length")
    return props, end


def _parse(first: int, body: bytes) -> Packet | None:
    """One packet from its first byte and body; None for a type a client ignores.

    Raises:
        MqttProtocolError: the body does not fit its type.
    """
    kind = first >> 4
    try:
        if kind == PUBLISH:
            qos = (first >> 1) & 0x03
            if qos > 1:
                raise MqttProtocolError(f"PUBLISH at QoS {qos}: this client subscribes at 0 or 1")
            n = _U16.unpack_from(body, 0)[0]
            at = 2 + n
            if at + 2 * qos > len(body):
                raise MqttProtocolError("PUBLISH is truncated: its topic runs past the packet")
            topic = body[2:at].decode("utf-8")
            packet_id = 0
            if qos:
                packet_id = _U16.unpack_from(body, at)[0]
                at += 2
            if at < len(body) and body[at] == 0:  # no properties: the usual case
                at += 1
            else:
                _, at = parse_properties(body, at)
            if at > len(body):
                raise MqttProtocolError("PUBLISH shorter than its header")
            return Publish(topic, body[at:], qos, bool(first & 1), packet_id)
        if kind == CONNACK:
            if len(body) < 2:
                raise MqttProtocolError("CONNACK shorter than 2 bytes")
            props, _ = parse_properties(body, 2) if len(body) > 2 else ({}, 2)
            return Ack(CONNACK, 0, (body[1],), props)
        if kind in (PUBACK, SUBACK):
            packet_id = _U16.unpack_from(body, 0)[0]
            if kind == PUBACK:
                code = body[2] if len(body) > 2 else 0
                props = parse_properties(body, 3)[0] if len(body) > 3 else {}
                return Ack(PUBACK, packet_id, (code,), props)
            props, at = parse_properties(body, 2)
            return Ack(SUBACK, packet_id, tuple(body[at:]), props)
        if kind == DISCONNECT:
            code = body[0] if body else 0
            props = parse_properties(body, 1)[0] if len(body) > 1 else {}
            return Ack(DISCONNECT, 0, (code,), props)
        if kind == PINGRESP:
            return Ping()
    except (struct.error, IndexError) as err:
        raise MqttProtocolError(f"packet type {kind} is truncated: {err}") from None
    except UnicodeDecodeError as err:
        raise MqttProtocolError(f"topic is not UTF-8: {err}") from None
    return None


class PacketReader:
    """Reassembles packets from a byte stream.

    Args:
        max_packet: largest packet accepted, bytes.
    """

    def __init__(self, max_packet: int = MAX_PACKET) -> None:
        self.max_packet = max_packet
        self._buf = bytearray()
        self._offset = 0
        """Bytes of the stream before the first one held in the buffer."""

    def feed(self, data: bytes) -> list[Packet]:
        """Add ``data`` and return every packet now complete, in order.

        Raises:
            MqttProtocolError: a malformed or oversized packet (the stream is lost);
                the message names the byte of the stream where that packet starts.
        """
        buf = self._buf
        buf += data
        out: list[Packet] = []
        at, size = 0, len(buf)
        try:
            while size - at >= 2:
                length, start = _varint_at(buf, at + 1, size)
                if length < 0:
                    break
                if length > self.max_packet:
                    raise MqttProtocolError(f"a {length}-byte packet exceeds {self.max_packet}")
                end = start + length
                if end > size:
                    break
                packet = _parse(buf[at], bytes(buf[start:end]))
                if packet is not None:
                    out.append(packet)
                at = end
        except MqttProtocolError as err:
            raise MqttProtocolError(
                f"{err} (the packet at byte {self._offset + at} of the stream)"
            ) from None
        if at:
            del buf[:at]
            self._offset += at
        return out

    @property
    def pending(self) -> int:
        """Bytes held of a packet not yet complete."""
        return len(self._buf)
