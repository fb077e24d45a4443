"""The link's MQTT 5 client: packets byte for byte, a stream cut anywhere, malformed
input refused, and interoperation with paho-mqtt (the reference client) through a
real mosquitto."""

from __future__ import annotations

import ssl
import threading
import time
from pathlib import Path

import pytest
from brokerhelp import Broker, Deployment
from hypothesis import given, settings
from hypothesis import strategies as st

from rfsas_hw.link.mqtt import open_mqtt
from rfsas_hw.link.mqtt_wire import (
    CONNACK,
    PUBACK,
    SUBACK,
    Ack,
    MqttProtocolError,
    PacketReader,
    Ping,
    Publish,
    connect_packet,
    framed,
    parse_properties,
    publish_head,
    publish_packet,
    subscribe_packet,
    varint,
)
from rfsas_hw.link.topics import Route, bearing_topic, nonce_topic


def test_variable_byte_integers_of_the_standard() -> None:
    # the boundary values of the standard's table 1.5.5
    assert varint(0) == b"\x00"
    assert varint(127) == b"\x7f"
    assert varint(128) == b"\x80\x01"
    assert varint(16_383) == b"\xff\x7f"
    assert varint(16_384) == b"\x80\x80\x01"
    assert varint(268_435_455) == b"\xff\xff\xff\x7f"
    with pytest.raises(ValueError):
        varint(268_435_456)


def test_connect_and_subscribe_layouts() -> None:
    packet = connect_packet("rfsas-1", 5)
    # CONNECT, length 20: "MQTT", version 5, clean start, keepalive 5, no properties, id
    assert packet == b"\x10\x14\x00\x04MQTT\x05\x02\x00\x05\x00\x00\x07rfsas-1"
    packet = subscribe_packet(7, [("a/#", 0), ("b", 1)])
    assert packet == b"\x82\x0d\x00\x07\x00\x00\x03a/#\x00\x00\x01b\x01"


def test_publish_with_expiry_parses_back() -> None:
    packet = publish_packet("t/1", b"xyz", qos=1, retain=True, packet_id=9, expiry_s=65)
    # flags: QoS 1, retain; properties: message expiry 65 s
    assert packet[0] == 0x33
    (got,) = PacketReader().feed(packet)
    assert got == Publish("t/1", b"xyz", qos=1, retain=True, packet_id=9)
    props, end = parse_properties(packet, 2 + 2 + 3 + 2)
    assert props == {0x02: 65} and packet[end:] == b"xyz"


@settings(max_examples=40, deadline=None)
@given(
    payloads=st.lists(st.binary(min_size=0, max_size=300), min_size=1, max_size=12),
    cuts=st.lists(st.integers(1, 50), min_size=1, max_size=40),
)
def test_a_stream_cut_anywhere_gives_the_same_packets(
    payloads: list[bytes], cuts: list[int]
) -> None:
    stream = b"".join(
        publish_packet(f"rfsas/v1/bearing/s-{i}", p, qos=i % 2, packet_id=i + 1)
        for i, p in enumerate(payloads)
    )
    stream += b"\xd0\x00"  # PINGRESP
    reader = PacketReader()
    got: list[object] = []
    at = 0
    for cut in cuts * 100:
        if at >= len(stream):
            break
        got += reader.feed(stream[at : at + cut])
        at += cut
    got += reader.feed(stream[at:])
    assert [p.payload for p in got if isinstance(p, Publish)] == payloads
    assert isinstance(got[-1], Ping) and reader.pending == 0


def test_acks_carry_their_reason_codes() -> None:
    reader = PacketReader()
    connack = b"\x20\x03\x00\x87\x00"  # not authorised
    puback = b"\x40\x04\x00\x05\x87\x00"
    suback = b"\x90\x05\x00\x06\x00\x00\x87"
    acks = reader.feed(connack + puback + suback + b"\x40\x02\x00\x06")
    assert [(a.kind, a.packet_id, a.reasons) for a in acks if isinstance(a, Ack)] == [
        (CONNACK, 0, (0x87,)),
        (PUBACK, 5, (0x87,)),
        (SUBACK, 6, (0x00, 0x87)),
        (PUBACK, 6, (0x00,)),
    ]
    assert [a.failed for a in acks if isinstance(a, Ack)] == [True, True, True, False]


@pytest.mark.parametrize(
    ("stream", "match"),
    [
        (b"\x30\xff\xff\xff\xff\x01", "four bytes"),
        (b"\x30" + varint(2 << 20), "exceeds"),
        (b"\x30\x03\x00\x05a", "truncated"),
        (b"\x32\x02\x00\x00", "truncated"),
        (b"\x34\x05\x00\x01a\x00\x01", "QoS 2"),
        (b"\x30\x05\x00\x01a\x01\x7f", "unknown property"),
        (b"\x30\x04\x00\x02\xff\xfe", "UTF-8"),
    ],
)
def test_malformed_packets_are_refused_with_the_reason(stream: bytes, match: str) -> None:
    with pytest.raises(MqttProtocolError, match=match):
        PacketReader().feed(stream)


def test_a_malformed_packet_is_refused_with_its_place_in_the_stream() -> None:
    reader = PacketReader()
    good = publish_packet("t/1", b"payload")
    bad = b"\x30\x05\x00\x01a\x01\x7f"  # a PUBLISH with an unknown property
    # a good packet, then the bad one split across two reads: its place counts from the
    # start of the stream, not of the read or of the buffer
    assert [p.payload for p in reader.feed(good + bad[:3]) if isinstance(p, Publish)] == [
        b"payload"
    ]
    with pytest.raises(MqttProtocolError, match=rf"unknown property .* at byte {len(good)} of"):
        reader.feed(bad[3:])


@pytest.mark.parametrize("size", [0, 1, 100, 118, 119, 120, 16_000, 20_000])
def test_a_publish_header_made_once_frames_the_same_bytes(size: int) -> None:
    # sizes across the remaining length's one- and two-byte forms (127 / 128 bytes after
    # a 9-byte header) and its two- and three-byte forms
    payload = bytes(range(256)) * (size // 256) + bytes(size % 256)
    for kwargs in ({}, {"retain": True}, {"expiry_s": 65}):
        first, head = publish_head("rfsas/v1/bearing/s-1/1/2", **kwargs)  # type: ignore[arg-type]
        assert framed(first, head, payload) == publish_packet(
            "rfsas/v1/bearing/s-1/1/2",
            payload,
            **kwargs,  # type: ignore[arg-type]
        )
    # the standard's layout: PUBLISH QoS 0, remaining length, topic, no properties, payload
    assert framed(*publish_head("t/1"), b"xyz") == b"\x30\x09\x00\x03t/1\x00xyz"


# --- interoperation with paho-mqtt through mosquitto ---


def _paho(broker: Broker, ident: str) -> object:
    mqtt = pytest.importorskip(
        "paho.mqtt.client", reason="needs the dev extra: pip install 'rfsas-hw[dev]'"
    )
    pair = broker.files.client(ident)
    client = mqtt.Client(
        callback_api_version=mqtt.CallbackAPIVersion.VERSION2,
        client_id=f"paho-{ident}",
        protocol=mqtt.MQTTv5,
    )
    client.tls_set(
        ca_certs=str(broker.files.ca_cert),
        certfile=str(pair.cert),
        keyfile=str(pair.key),
        tls_version=ssl.PROTOCOL_TLS_CLIENT,
    )
    connected = threading.Event()
    client.on_connect = lambda *a: connected.set()
    client.connect(broker.files.host, broker.files.port, 30)
    client.loop_start()
    assert connected.wait(5), f"paho client {ident} did not connect"
    return client


def test_paho_publishes_and_this_client_receives(broker: Broker, deployment: Deployment) -> None:
    props_mod = pytest.importorskip(
        "paho.mqtt.properties", reason="needs the dev extra: pip install 'rfsas-hw[dev]'"
    )
    types = pytest.importorskip(
        "paho.mqtt.packettypes", reason="needs the dev extra: pip install 'rfsas-hw[dev]'"
    )
    ours = open_mqtt(broker.url("rsu-1", nonces="rsu-1"), "recv")
    sensor = _paho(broker, "rsu-1")
    authority = _paho(broker, "auth-0")
    try:
        topic = bearing_topic("rsu-1", "1" * 16)
        bearing = bytes(range(200))
        listener = open_mqtt(broker.url("be-a"), "recv")
        sensor.publish(topic, bearing, qos=0)  # type: ignore[attr-defined]
        assert listener.recv_from(5) == (bearing, topic)
        listener.close()
        props = props_mod.Properties(types.PacketTypes.PUBLISH)
        props.MessageExpiryInterval = 30
        envelope = b"\x00\x01envelope" * 10
        info = authority.publish(  # type: ignore[attr-defined]
            nonce_topic("rsu-1", 42), envelope, qos=1, retain=True, properties=props
        )
        info.wait_for_publish(5)
        assert ours.recv_from(5) == (envelope, nonce_topic("rsu-1", 42))
    finally:
        for client in (sensor, authority):
            client.loop_stop()  # type: ignore[attr-defined]
            client.disconnect()  # type: ignore[attr-defined]
        ours.close()


def test_this_client_publishes_and_paho_receives(broker: Broker, deployment: Deployment) -> None:
    got: list[tuple[str, bytes, int, bool]] = []
    arrived = threading.Event()
    backend = _paho(broker, "be-a")
    backend.on_message = lambda c, u, m: (  # type: ignore[attr-defined]
        got.append((m.topic, bytes(m.payload), m.qos, m.retain)),
        arrived.set() if len(got) >= 2 else None,
    )
    subscribed = threading.Event()
    backend.on_subscribe = lambda *a: subscribed.set()  # type: ignore[attr-defined]
    backend.subscribe("rfsas/v1/#", qos=1)  # type: ignore[attr-defined]
    assert subscribed.wait(5)
    sensor = open_mqtt(broker.url("rsu-1"), "send")
    authority = open_mqtt(broker.url("auth-0"), "send")
    try:
        topic = bearing_topic("rsu-1", "2" * 16)
        sensor.publish(Route(topic), b"\x01" * 150)
        authority.publish(Route(nonce_topic("be-a", 7), 1, True, 20), b"\x02" * 90)
        assert arrived.wait(5), got
        deadline = time.monotonic() + 5
        while authority.stats.refused == 0 and authority._pending and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        sensor.close()
        authority.close()
        backend.loop_stop()  # type: ignore[attr-defined]
        backend.disconnect()  # type: ignore[attr-defined]
    assert (topic, b"\x01" * 150, 0, False) in got
    assert (nonce_topic("be-a", 7), b"\x02" * 90, 1, False) in got
    assert authority.stats.refused == 0 and not authority._pending  # PUBACK arrived


def test_unreachable_broker_is_one_clear_error(tmp_path: Path) -> None:
    from rfsas_hw.errors import LinkError

    with pytest.raises(LinkError, match=r"mqtt://127\.0\.0\.1:1: no connection within 0\.5 s"):
        open_mqtt("mqtt://127.0.0.1:1?connect_s=0.5", "recv")


def test_qos1_publishes_respect_the_brokers_receive_maximum(
    broker: Broker, deployment: Deployment
) -> None:
    """mosquitto takes 100 unacknowledged QoS-1 publishes; 250 at once must all arrive."""
    authority = open_mqtt(broker.url("auth-0"), "send")
    try:
        assert authority._receive_max < 250
        for i in range(250):
            authority.publish(Route(nonce_topic("be-a", i), 1, True, 30), b"e" * 60)
    finally:
        authority.close()
    assert authority.stats.sent == 250 and authority.stats.disconnects == 0
    assert not authority._pending
