"""The link through a real mosquitto with mutual TLS and ACLs: the broker is not trusted.

Sensor → broker → backend with version-2 (pre-authenticated) messages and the
backend's nonce from a retained envelope; an unauthorised publish refused; forged,
tampered and mis-topicked messages rejected; the broker killed while UDP runs
alongside loses nothing; retained nonce envelopes expire.
"""

from __future__ import annotations

import os
import socket
import time

import pytest
from brokerhelp import Broker, Deployment
from fleethelp import ORIGIN, SCHEDULE, bearings_now, drain, well_inside_an_epoch

from rfsas_hw.errors import LinkError
from rfsas_hw.link import Publisher, Receiver, ReceiverConfig, SafetyMessage
from rfsas_hw.link.mqtt import MqttTransport, open_mqtt
from rfsas_hw.link.preauth import derive_key, seal
from rfsas_hw.link.topics import ZOOM, Route, bearing_topic, nonce_topic, topic_sender
from rfsas_hw.records import Pose

POSE = Pose(12.0, -30.0, 90.0)
EXPIRY_S = 4
"""Message expiry of the retained envelope in the expiry test, seconds."""


def _free_udp() -> str:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return f"udp://127.0.0.1:{s.getsockname()[1]}"


def _publish_nonces(broker: Broker, deployment: Deployment) -> None:
    authority = deployment.nonces
    tx = open_mqtt(broker.url("auth-0"), "send")
    try:
        for rid in authority.receivers:
            for epoch in authority.due(time.time_ns()):
                tx.send(authority.seal(rid, epoch))
    finally:
        tx.close()


def _backend_rx(broker: Broker, deployment: Deployment, **config: object) -> Receiver:
    store = deployment.backends["be-a"]
    cfg = ReceiverConfig(epoch_s=SCHEDULE.epoch_s, grace_s=SCHEDULE.grace_s, **config)  # type: ignore[arg-type]
    return Receiver.listen(
        broker.url("be-a", nonces="be-a", sub="rfsas/v1/bearing/#"),
        store.trust,
        store.nonce_store(SCHEDULE),
        cfg,
    )


def _wait_nonces(rx: Receiver, n: int = 2) -> None:
    deadline = time.monotonic() + 5
    while rx.stats.nonces < n and time.monotonic() < deadline:
        rx.receive(timeout=0.05)
    assert rx.stats.nonces == n, rx.stats.as_dict()


def test_sensor_to_backend_through_the_broker(broker: Broker, deployment: Deployment) -> None:
    well_inside_an_epoch()
    _publish_nonces(broker, deployment)
    rx = _backend_rx(broker, deployment, accept_v1=False)
    signer = deployment.sensors["rsu-1"].signer()
    pub = Publisher.to_url(
        broker.url("rsu-1", origin=ORIGIN),
        signer,
        POSE,
        preauth=deployment.nonces,
    )
    try:
        _wait_nonces(rx)  # retained: the backend subscribed after they were published
        for i in range(20):
            pub.on_bearings(bearings_now("rsu-1", 3, seed=i))
        got = drain(rx, 20)
    finally:
        pub.close()
        rx.close()
    assert len(got) == 20, rx.stats.as_dict()
    assert {m.sender_id for m in got} == {"rsu-1"}
    assert rx.stats.rejected_total == 0
    assert max(m.age_s for m in got) < 1.0


def test_publishes_held_together_arrive_whole_and_in_order(
    broker: Broker, deployment: Deployment
) -> None:
    """Messages published in one ``together`` block leave in one write at its end: all
    arrive, in the order published, and are counted sent once written; blocks do not
    nest."""
    rx = open_mqtt(broker.url("be-a"), "recv")
    pub = Publisher.to_url(
        broker.url("rsu-1", origin=ORIGIN), deployment.sensors["rsu-1"].signer(), POSE
    )
    transport = pub.transport
    assert isinstance(transport, MqttTransport)
    try:
        sent: list[bytes] = []
        transport.send = sent.append  # type: ignore[method-assign]
        for i in range(30):  # the signed datagrams, made without sending them
            pub.on_bearings(bearings_now("rsu-1", 2, seed=i))
        del transport.send
        before = transport.stats.sent
        with transport.together() as held:
            for datagram in sent:
                transport.send(datagram)
            assert transport.stats.sent == before  # held, not written yet
            with pytest.raises(LinkError, match="already held"), transport.together():
                pass
        assert (held.written, held.lost) == (30, 0)
        assert transport.stats.sent == before + 30
        got = [rx.recv_from(5) for _ in range(30)]
    finally:
        pub.close()
        rx.close()
    assert [g[0] for g in got if g is not None] == sent


def test_topic_has_one_level_per_quadkey_digit(broker: Broker, deployment: Deployment) -> None:
    rx = open_mqtt(broker.url("be-a"), "recv")
    pub = Publisher.to_url(
        broker.url("rsu-1", origin=ORIGIN), deployment.sensors["rsu-1"].signer(), POSE
    )
    try:
        pub.on_bearings(bearings_now("rsu-1"))
        got = rx.recv_from(5)
        for transport in (pub.transport, rx):
            sock = transport.socket()  # type: ignore[attr-defined]
            assert sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) != 0  # Nagle off
    finally:
        pub.close()
        rx.close()
    assert got is not None
    _, topic = got
    assert topic is not None
    levels = topic.split("/")
    assert levels[:4] == ["rfsas", "v1", "bearing", "rsu-1"]
    assert len(levels) == 4 + ZOOM and all(d in "0123" for d in levels[4:])
    assert topic_sender(topic) == "rsu-1"


def test_unauthorised_publish_is_refused(broker: Broker, deployment: Deployment) -> None:
    rx = open_mqtt(broker.url("be-a"), "recv")
    tx = open_mqtt(broker.url("rsu-1"), "send")
    try:
        signed = deployment.sensors["rsu-1"].signer()
        msg = SafetyMessage("rsu-1", POSE, time.time_ns() // 1000, 1, 0, bearings_now("rsu-1"))
        # rsu-1 may write only below rfsas/v1/bearing/rsu-1/
        tx.publish(Route(bearing_topic("rsu-2", "1" * ZOOM), qos=1), signed.encode(msg))
        deadline = time.monotonic() + 5
        while tx.stats.refused == 0 and time.monotonic() < deadline:
            time.sleep(0.02)
        nothing = rx.recv_from(0.5)
    finally:
        tx.close()
        rx.close()
    assert tx.stats.refused == 1
    assert nothing is None


def test_forged_tampered_and_mistopicked_messages_are_rejected(
    broker: Broker, deployment: Deployment
) -> None:
    well_inside_an_epoch()
    _publish_nonces(broker, deployment)
    rx = _backend_rx(broker, deployment)
    tx = open_mqtt(broker.url("rsu-1"), "send")
    authority = deployment.nonces
    s1 = deployment.sensors["rsu-1"].signer()
    s2 = deployment.sensors["rsu-2"].signer()
    topic1 = bearing_topic("rsu-1", "0" * ZOOM)
    try:
        _wait_nonces(rx)
        now_us = time.time_ns() // 1000
        b = bearings_now("rsu-1")
        epoch = SCHEDULE.epoch_of(int(b.t_ns.min()))
        key1 = authority.nonce_for(epoch)

        def msg(sender: str, seq: int) -> SafetyMessage:
            return SafetyMessage(sender, POSE, now_us, seq, epoch, bearings_now(sender, seed=seq))

        good = seal(s1, msg("rsu-1", 1), derive_key(key1, "rsu-1"))
        forged_v1 = s1.encode(msg("rsu-1", 2))[:-64] + os.urandom(64)
        forged_v2 = good[:-8] + os.urandom(8)  # no key: the tag cannot be made
        tampered = bytearray(seal(s1, msg("rsu-1", 3), derive_key(key1, "rsu-1")))
        tampered[60] ^= 0x01
        # validly signed by rsu-2, but published on rsu-1's topic (rsu-1's credentials)
        other = seal(s2, msg("rsu-2", 4), derive_key(key1, "rsu-2"))
        for payload in (forged_v1, forged_v2, bytes(tampered), other, good):
            tx.publish(Route(topic1), payload)
        got = drain(rx, 1, timeout_s=10, until=lambda: rx.stats.datagrams >= 7)
        time.sleep(0.2)
        got += rx.receive(timeout=0.1)
    finally:
        tx.close()
        rx.close()
    assert [m.message.seq for m in got] == [1]
    assert rx.stats.rejected == {
        "bad_signature": 1,
        "bad_preauth": 2,
        "topic_mismatch": 1,
    }


def test_broker_killed_while_udp_runs_alongside_loses_nothing(
    broker: Broker, deployment: Deployment
) -> None:
    udp = _free_udp()
    store = deployment.backends["be-a"]
    rx = Receiver.listen([broker.url("be-a"), udp], store.trust)
    pub = Publisher.to_url(
        [broker.url("rsu-1", origin=ORIGIN), udp], deployment.sensors["rsu-1"].signer(), POSE
    )
    sent = 60
    got = []
    try:
        for i in range(sent):
            if i == sent // 3:
                broker.kill()
            pub.on_bearings(bearings_now("rsu-1", 2, seed=i))
            got += rx.receive(timeout=0.01)
        got += drain(rx, sent - len(got), timeout_s=3)
        counters = rx.counters()
    finally:
        pub.close()
        rx.close()
    assert len({m.message.seq for m in got}) == sent
    assert len(got) == sent
    assert pub.stats.messages == sent and pub.stats.dropped == {}
    # every second copy (through the broker before it died, or on UDP) is a replay
    assert rx.stats.rejected == {"replay": rx.stats.datagrams - sent}
    assert rx.stats.rejected["replay"] >= 1
    # the broker's side of the counters: it carried some, then went away
    assert 1 <= counters["mqtt.received"] < sent
    assert counters["mqtt.disconnects"] >= 1


def test_retained_nonce_envelope_is_delivered_late_and_then_expires(
    broker: Broker, deployment: Deployment
) -> None:
    authority = deployment.nonces
    epoch = SCHEDULE.epoch_of(time.time_ns())
    envelope = authority.seal("rsu-2", epoch)
    tx = open_mqtt(broker.url("auth-0"), "send")
    try:
        routed = tx.router.route(envelope, time.time_ns())
        assert routed.topic == nonce_topic("rsu-2", epoch)
        assert routed.retain and routed.qos == 1
        assert routed.expiry_s is not None and 0 < routed.expiry_s <= 65
        tx.publish(Route(routed.topic, 1, True, EXPIRY_S), envelope)
        published = time.monotonic()
    finally:
        tx.close()
    late = open_mqtt(broker.url("rsu-2", nonces="rsu-2"), "recv")
    try:
        got = late.recv_from(3)
    finally:
        late.close()
    assert got == (envelope, nonce_topic("rsu-2", epoch))
    time.sleep(max(0.0, published + EXPIRY_S + 1.0 - time.monotonic()))
    later = open_mqtt(broker.url("rsu-2", nonces="rsu-2"), "recv")
    try:
        assert later.recv_from(0.7) is None
    finally:
        later.close()


def test_clients_reconnect_and_resubscribe_after_a_broker_restart(
    broker: Broker, deployment: Deployment
) -> None:
    store = deployment.backends["be-a"]
    rx = Receiver.listen(broker.url("be-a"), store.trust)
    pub = Publisher.to_url(
        broker.url("rsu-1", origin=ORIGIN), deployment.sensors["rsu-1"].signer(), POSE
    )
    try:
        pub.on_bearings(bearings_now("rsu-1", seed=1))
        assert len(drain(rx, 1)) == 1
        broker.kill()
        pub.on_bearings(bearings_now("rsu-1", seed=2))  # refused while the broker is gone
        broker.start()
        got = []
        deadline = time.monotonic() + 20
        while not got and time.monotonic() < deadline:
            pub.on_bearings(bearings_now("rsu-1", seed=3))
            got = rx.receive(timeout=0.2)
        tx_stats = pub.transport.stats  # type: ignore[attr-defined]
        rx_stats = rx.transport.stats  # type: ignore[union-attr]
    finally:
        pub.close()
        rx.close()
    assert got, "no message after the broker came back"
    assert tx_stats.connects >= 2 and rx_stats.connects >= 2
    assert tx_stats.disconnects >= 1 and rx_stats.disconnects >= 1
    assert pub.stats.dropped["send_error"] >= 1
