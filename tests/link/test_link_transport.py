"""Transports and the publisher over real loopback sockets (unicast and multicast)."""

from __future__ import annotations

import os
import socket
import time
import types

import numpy as np
import pytest
from linkhelp import NOW_NS, SCHEDULE, Kept, bearings, message

import rfsas_hw.link.receiver as receiver_module
from rfsas_hw.errors import LinkError
from rfsas_hw.link import (
    Publisher,
    Receiver,
    ReceiverConfig,
    Signer,
    TrustedKeys,
    UdpTransport,
    VerifiedMessage,
    open_transport,
    parse_url,
)
from rfsas_hw.link.message import decode
from rfsas_hw.link.publisher import SNR_UNKNOWN_DB
from rfsas_hw.records import Pose

POSE = Pose(5.0, 6.0, 370.0)


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def drain(rx: Receiver, want: int, rounds: int = 50) -> list[VerifiedMessage]:
    got: list[VerifiedMessage] = []
    for _ in range(rounds):
        got += rx.receive(timeout=0.1)
        if len(got) >= want:
            break
    return got


@pytest.mark.parametrize(
    ("url", "host", "port", "multicast"),
    [
        ("udp://127.0.0.1:47000", "127.0.0.1", 47000, False),
        ("udp://localhost:1", "localhost", 1, False),
        ("udp://239.255.42.1:5000", "239.255.42.1", 5000, True),
        ("udp://239.255.42.1:5000?iface=127.0.0.1&ttl=3", "239.255.42.1", 5000, True),
        ("udp://127.0.0.1:5000?rcvbuf=65536", "127.0.0.1", 5000, False),
    ],
)
def test_parse_url(url: str, host: str, port: int, multicast: bool) -> None:
    ep = parse_url(url)
    assert (ep.host, ep.port, ep.multicast) == (host, port, multicast)


@pytest.mark.parametrize(
    ("url", "match"),
    [
        ("tcp://127.0.0.1:1", "unsupported transport"),
        ("udp://127.0.0.1", "HOST:PORT"),
        ("udp://127.0.0.1:99999", "bad port"),
        ("udp://239.1.1.1:5?hops=2", "unknown option"),
        ("udp://239.1.1.1:5?ttl=x", "bad iface, ttl or rcvbuf"),
        ("udp://127.0.0.1:5?rcvbuf=10", "rcvbuf 10 outside"),
        ("udp://239.1.1.1:5?ttl=300", "outside 0-255"),
    ],
)
def test_bad_urls(url: str, match: str) -> None:
    with pytest.raises(LinkError, match=match):
        parse_url(url)


def test_unicast_publish_split_by_size_and_epoch(signer: Signer, trust: TrustedKeys) -> None:
    port = free_port()
    url = f"udp://127.0.0.1:{port}"
    rx = Receiver.listen(url, trust, config=ReceiverConfig(check_epoch=False), clock=lambda: NOW_NS)
    batch = bearings("ignored-name", 100, NOW_NS)
    k = SCHEDULE.epoch_of(NOW_NS)
    # 10 bearings, not in time order, were captured in the previous epoch
    batch.t_ns[40:50] = SCHEDULE.start_ns(k) - 1_000_000
    batch.azimuth_deg[0] = np.nan  # an invalid row is dropped, not sent
    pub = Publisher.to_url(url, signer, POSE, max_datagram=600, clock=lambda: NOW_NS)
    try:
        pub.on_bearings(batch)
        pub.on_bearings(batch.select(slice(0, 0)))
        assert pub.stats.dropped == {"invalid": 1}
        got = drain(rx, pub.stats.messages)
    finally:
        pub.close()
        rx.close()
    per_msg = (600 - 39 - 5 - 64) // 30
    assert pub.stats.messages == -(-89 // per_msg) + 1
    assert len(got) == pub.stats.messages and rx.stats.rejected_total == 0
    assert {m.message.epoch for m in got} == {k, k - 1}
    assert all(len(m.bearings) <= per_msg for m in got)
    assert sorted(m.message.seq for m in got) == [
        (got[0].message.seq + i) % 2**32 for i in range(len(got))
    ]
    assert all(m.message.pose == Pose(5.0, 6.0, 10.0) for m in got)
    sent = np.sort(np.concatenate([m.bearings.emitter for m in got]))
    np.testing.assert_array_equal(sent, np.sort(batch.emitter[1:]))


def test_the_publisher_drops_every_row_the_wire_cannot_carry_and_sends_the_rest(
    signer: Signer,
) -> None:
    batch = bearings("x", 9, NOW_NS)
    batch.azimuth_deg[0] = 365.0  # finite but off the compass (was sent as 0 before)
    batch.azimuth_deg[1] = np.inf
    batch.sigma_deg[2] = 0.0
    batch.channel[3] = -1
    batch.t_ns[4] = -5_000
    batch.snr_db[5] = np.inf
    batch.snr_db[6] = np.nan  # a unit that measures no SNR: sent, with the marker
    batch.azimuth_deg[7] = 359.99999  # rounds to 360.0 in float32: sent as 0
    kept = Kept()
    pub = Publisher(signer, kept, POSE, clock=lambda: NOW_NS)
    pub.on_bearings(batch)
    assert pub.stats.dropped == {"invalid": 6} and pub.stats.offered == 9
    (raw,) = kept.sent
    got = decode(raw).bearings
    np.testing.assert_array_equal(got.emitter, batch.emitter[6:])
    assert got.snr_db[0] == SNR_UNKNOWN_DB and got.azimuth_deg[1] == 0.0
    np.testing.assert_allclose(got.azimuth_deg[2], batch.azimuth_deg[8], atol=1e-4)
    # all of them bad: nothing sent, all counted
    pub.on_bearings(batch.select(slice(0, 6)))
    assert pub.stats.dropped == {"invalid": 12} and len(kept.sent) == 1


def test_a_bearing_goes_in_the_epoch_a_receiver_finds_from_its_time_on_the_wire(
    signer: Signer,
) -> None:
    # 1 ns before an epoch starts, its µs on the wire are still in the epoch before
    k = SCHEDULE.epoch_of(NOW_NS)
    batch = bearings("x", 3, NOW_NS)
    batch.t_ns[:] = [SCHEDULE.start_ns(k) - 1, SCHEDULE.start_ns(k), SCHEDULE.start_ns(k) - 2_000]
    kept = Kept()
    pub = Publisher(signer, kept, POSE, clock=lambda: NOW_NS, epoch_s=SCHEDULE.epoch_s)
    pub.on_bearings(batch)
    msgs = [decode(raw) for raw in kept.sent]
    assert [m.epoch for m in msgs] == [k - 1, k]
    for m in msgs:
        assert {int(t) // SCHEDULE.epoch_ns for t in m.bearings.t_ns} == {m.epoch}
    assert [len(m.bearings) for m in msgs] == [2, 1]


def test_multicast_on_loopback_reaches_two_receivers(signer: Signer, trust: TrustedKeys) -> None:
    url = f"udp://239.255.77.{np.random.default_rng().integers(1, 250)}:{free_port()}"
    receivers = [
        Receiver.listen(url, trust, config=ReceiverConfig(check_epoch=False), clock=lambda: NOW_NS)
    ]
    receivers.append(
        Receiver.listen(url, trust, config=ReceiverConfig(check_epoch=False), clock=lambda: NOW_NS)
    )
    pub = Publisher.to_url(url, signer, POSE, clock=lambda: NOW_NS)
    try:
        pub.on_bearings(bearings("x", 5, NOW_NS))
        for rx in receivers:
            (msg,) = drain(rx, 1)
            assert len(msg.bearings) == 5
    finally:
        pub.close()
        for rx in receivers:
            rx.close()


def test_send_error_is_counted_and_the_publisher_goes_on(signer: Signer) -> None:
    class Refusing(UdpTransport):
        def send(self, datagram: bytes) -> None:
            raise LinkError("no route")

    pub = Publisher(signer, Refusing(parse_url("udp://127.0.0.1:9"), "send"), POSE)
    pub.on_bearings(bearings("x", 3, NOW_NS))
    pub.on_bearings(bearings("x", 2, NOW_NS))
    assert pub.stats.dropped == {"send_error": 5} and pub.stats.messages == 0
    pub.close()
    pub.close()


def test_kernel_refuses_an_impossible_datagram() -> None:
    with open_transport("udp://127.0.0.1:9", "send") as tx:
        with pytest.raises(LinkError, match="cannot send 70000 bytes"):
            tx.send(bytes(70000))
        assert tx.send_errors == 1


def test_recv_returns_whole_oversized_datagrams_and_none_on_timeout(trust: TrustedKeys) -> None:
    port = free_port()
    rx = Receiver.listen(f"udp://127.0.0.1:{port}", trust)
    with open_transport(f"udp://127.0.0.1:{port}", "send") as tx:
        tx.send(b"RF" + bytes(3000))
        assert drain(rx, 1, rounds=3) == []
    assert rx.stats.rejected == {"oversized": 1}
    assert rx.receive(timeout=0.01) == []
    rx.close()
    with pytest.raises(LinkError, match="no transport"):
        Receiver(trust).receive(0)


def test_binding_a_taken_port_is_a_link_error(trust: TrustedKeys) -> None:
    port = free_port()
    first = open_transport(f"udp://127.0.0.1:{port}", "recv")
    try:
        with pytest.raises(LinkError, match="cannot open for recv"):
            open_transport(f"udp://127.0.0.1:{port}", "recv")
    finally:
        first.close()


def test_overload_checks_newest_first_and_sheds_signature_checks(
    signer: Signer, trust: TrustedKeys, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the signature checks are timed on a counter that moves 1 ms per reading, so
    # every check "takes" 1 ms whatever the machine's speed or load
    ticks = iter(range(10**6))
    fake_time = types.SimpleNamespace(
        perf_counter=lambda: next(ticks) * 1e-3, monotonic=time.monotonic
    )
    monkeypatch.setattr(receiver_module, "time", fake_time)
    port = free_port()
    # 250 queued datagrams; after 4 signature checks (4 ms) the 3.5 ms budget is spent
    cfg = ReceiverConfig(check_epoch=False, backlog=10, shed_after_s=0.0035)
    rx = Receiver.listen(
        f"udp://127.0.0.1:{port}?rcvbuf=4194304", trust, config=cfg, clock=lambda: NOW_NS
    )
    valid = signer.encode(message(seq=1))
    forged = [signer.encode(message(seq=100 + i))[:-64] + os.urandom(64) for i in range(200)]
    with open_transport(f"udp://127.0.0.1:{port}", "send") as tx:
        for i, d in enumerate(forged):
            tx.send(d)
            if i % 4 == 0:
                tx.send(b"junk datagram")
        tx.send(valid)
    try:
        got = drain(rx, 1, rounds=5)
    finally:
        rx.close()
    assert [m.message.seq for m in got] == [1]
    rej = rx.stats.rejected
    assert rej["bad_magic"] == 50  # cheap checks still run on everything
    # the valid newest one and three forged ones are checked, the other 197 shed
    assert rej["bad_signature"] == 3
    assert rej["overload"] == 197
