"""What one bearing message costs at each end, through mosquitto (mutual TLS, loopback).

    python bench/bench_messages.py [N]
    python bench/bench_messages.py --client [N]

Needs ``mosquitto`` (Debian package); paho-mqtt (the ``dev`` extra) for the rows
beside. The broker is started as ``bench_fleet.py`` starts it (mutual TLS, the
ACL of ``rfsas broker config``). For 1, 2, 4 and 8 bearings a message, N
messages (default 2,000) go at 500 a second, 10 every 20 ms (a district
backend takes about 400 a second):

- send: a sensor's :class:`~rfsas_hw.link.publisher.Publisher` (``on_bearings``:
  the rows as the wire holds them, checked, the pre-authentication tag, the
  ECDSA P-256 signature, the MQTT publish over TLS) — what a district's twin
  worker runs once per unit and slot with bearings; beside it what a user would
  otherwise write at the least: the bare ``cryptography`` sign of an already
  encoded message and a paho-mqtt 2 publish (MQTT 5, TLS, its network thread);
- receive (a child process): a backend's :class:`~rfsas_hw.link.receiver.Receiver`
  on ``open_mqtt`` (``receive``: the MQTT reads and every check in order,
  header times, tag, signature, decoding, replay, latency); beside it a
  paho-mqtt 2 ``on_message`` that only verifies the signature.

``--client``: the MQTT client alone, each side — a sensor's transport publishing
N pre-signed 2-bearing messages (``send``: the route, the PUBLISH packet, the TLS
record and its write) and a backend's transport taking them (``recv_many``: the
socket reads, TLS, the packets), at the same pace; CPU µs per message, user and
system, so that a change to the client shows without the signing and checks around it.

CPU µs per message (the process's, every thread, over the messages) and per
bearing: the cost per message is nearly flat in the bearings it carries, so
fewer, fuller messages (a longer slot) cost less per bearing. One run on a
possibly shared machine; ratios from the same run.
"""

from __future__ import annotations

import argparse
import importlib.util
import logging
import resource
import sys
import tempfile
import threading
import time
from multiprocessing.queues import Queue as MpQueue
from pathlib import Path

import numpy as np
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.asymmetric import ec

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_fleet import start_broker
from bench_mqtt_client import paho_receive, ready_process, setup

from rfsas_hw.fleet.broker import BrokerFiles
from rfsas_hw.link import Publisher, Receiver, ReceiverConfig, TrustedKeys
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.link.message import SafetyMessage, encode_body
from rfsas_hw.link.mqtt import open_mqtt
from rfsas_hw.link.preauth import PreauthKeys
from rfsas_hw.link.topics import TopicRouter
from rfsas_hw.privacy.hashing import FixedNonce
from rfsas_hw.records import BearingBatch, Pose

logging.disable(logging.WARNING)

ORIGIN_Q = "52.43,13.53"
NONCE = bytes(range(32))
POSE = Pose(120.0, -40.0, 45.0)
RATE = 500.0
TICK_S = 0.02
IDLE_S = 3.0
"""A receiver that hears nothing for this long after the first message is done."""
FILTER = "rfsas/v1/bearing/#"
ECDSA = ec.ECDSA(hashes.SHA256())
PAHO_KEY = 0x5EED_BEEF
"""The private value of the key the paho rows sign with (both ends derive it)."""


def _batch(k: int, i: int) -> BearingBatch:
    """``k`` bearings of now (different emitters, as one unit's frames of a slot)."""
    t = time.time_ns() - np.arange(k, dtype=np.int64) * 1_000_000
    return BearingBatch(
        "s-0",
        t,
        np.linspace(10.0, 300.0, k) + i % 7,
        np.full(k, 2.5),
        np.full(k, 18.0),
        np.full(k, 6, np.int16),
        np.arange(k, dtype=np.uint64) + 1000 * (i % 50),
    )


def _paced(n: int, send: object) -> None:
    """Call ``send(i)`` for i < n at :data:`RATE` a second, a tick's worth at a time."""
    per_tick = int(RATE * TICK_S)
    start = time.monotonic()
    for i in range(n):
        send(i)  # type: ignore[operator]
        if (i + 1) % per_tick == 0:
            pause = start + (i + 1) / RATE - time.monotonic()
            if pause > 0:
                time.sleep(pause)


def send_ours(files: BrokerFiles, signer_dir: Path, k: int, n: int) -> float:
    """CPU µs per message of ``Publisher.on_bearings`` over TLS."""
    signer = KeyStore.open(signer_dir).signer()
    pub = Publisher.to_url(
        files.url("s-0", origin=ORIGIN_Q), signer, POSE, preauth=FixedNonce(NONCE)
    )
    batches = [_batch(k, i) for i in range(n)]
    try:
        t0 = time.process_time()
        _paced(n, lambda i: pub.on_bearings(batches[i]))
        cpu = time.process_time() - t0
        assert pub.stats.messages == n, pub.stats.as_dict()
    finally:
        pub.close()
    return cpu / n * 1e6


def send_paho(files: BrokerFiles, signer_dir: Path, k: int, n: int) -> float:
    """CPU µs per message of a bare ECDSA sign (DER, appended to a message encoded once)
    and a paho-mqtt publish over TLS."""
    import paho.mqtt.client as mqtt

    key = ec.derive_private_key(PAHO_KEY, ec.SECP256R1())
    body = encode_body(SafetyMessage("s-0", POSE, time.time_ns() // 1000, 1, 0, _batch(k, 0)))
    pair = files.client("s-0")
    client = mqtt.Client(
        mqtt.CallbackAPIVersion.VERSION2, client_id="bench-paho-send", protocol=mqtt.MQTTv5
    )
    client.tls_set(str(files.ca_cert), str(pair.cert), str(pair.key))
    connected = threading.Event()
    client.on_connect = lambda *_: connected.set()
    client.connect(files.host, files.port, keepalive=30)
    client.loop_start()
    try:
        if not connected.wait(20):
            raise RuntimeError("paho-mqtt did not connect within 20 s")
        topic = _topic(files)
        t0 = time.process_time()
        _paced(n, lambda i: client.publish(topic, body + key.sign(body, ECDSA), qos=0))
        cpu = time.process_time() - t0
    finally:
        client.disconnect()
        client.loop_stop()
    return cpu / n * 1e6


def _topic(files: BrokerFiles) -> str:
    """The bearing topic of sensor s-0 at POSE (what its publisher routes to)."""
    from rfsas_hw.link.mqtt import parse_mqtt_url

    origin = parse_mqtt_url(files.url("s-0", origin=ORIGIN_Q)).origin
    router = TopicRouter(origin)
    raw = encode_body(SafetyMessage("s-0", POSE, 0, 0, 0, _batch(1, 0))) + bytes(64)
    return router.route(raw, 0).topic


def recv_ours(files: BrokerFiles, key_dir: str, n: int, q: MpQueue[object]) -> None:
    trust = TrustedKeys({"s-0": KeyStore.open(Path(key_dir)).signer().public_key})
    rx = Receiver.listen(
        files.url("be-0", sub=FILTER, queue="1000000"),
        trust,
        # every message checked in full (no shedding when a busy machine lets a backlog
        # build up): the cost per message is what is measured
        config=ReceiverConfig(backlog=1 << 30),
        preauth=PreauthKeys(FixedNonce(NONCE)),
    )
    time.sleep(0.5)  # the subscription settles
    q.put("ready")
    got, t0 = 0, time.process_time()
    while got < n:
        msgs = rx.receive(timeout=IDLE_S if got else 60.0)
        if not msgs:
            break
        got += len(msgs)
    cpu = time.process_time() - t0
    q.put((got, cpu, dict(rx.stats.rejected)))
    rx.close()


def recv_paho(files: BrokerFiles, key_dir: str, n: int, q: MpQueue[object]) -> None:
    public = ec.derive_private_key(PAHO_KEY, ec.SECP256R1()).public_key()

    def check(raw: bytes) -> None:
        # the sender appends a DER signature to a message encoded once: its length
        # follows from the bearing count byte
        n_rows = raw[6 + raw[5] + 32]
        end = 6 + raw[5] + 33 + 30 * n_rows
        public.verify(raw[end:], raw[:end], ECDSA)

    paho_receive(files, n, q, "bench-paho-recv", check, tail=(0,))


def _usage() -> tuple[float, float]:
    """This process's user and system CPU seconds so far."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime, r.ru_stime


def send_client(files: BrokerFiles, signer_dir: Path, k: int, n: int) -> tuple[float, float]:
    """User and system CPU µs per message of ``MqttTransport.send`` of pre-signed messages."""
    signer = KeyStore.open(signer_dir).signer()
    datagrams = [
        signer.encode(SafetyMessage("s-0", POSE, time.time_ns() // 1000, i, 0, _batch(k, i)))
        for i in range(n)
    ]
    transport = open_mqtt(files.url("s-0", origin=ORIGIN_Q), "send")
    try:
        u0, s0 = _usage()
        _paced(n, lambda i: transport.send(datagrams[i]))
        u1, s1 = _usage()
        assert transport.stats.sent == n, transport.stats.as_dict()
    finally:
        transport.close()
    return (u1 - u0) / n * 1e6, (s1 - s0) / n * 1e6


def recv_client(files: BrokerFiles, key_dir: str, n: int, q: MpQueue[object]) -> None:
    transport = open_mqtt(files.url("be-0", sub=FILTER, queue="1000000"), "recv")
    time.sleep(0.5)  # the subscription settles
    q.put("ready")
    got = 0
    u0, s0 = _usage()
    while got < n:
        batch = transport.recv_many(timeout=IDLE_S if got else 60.0)
        if not batch:
            break
        got += len(batch)
    u1, s1 = _usage()
    q.put((got, u1 - u0, s1 - s0))
    transport.close()


def client_only(n: int) -> None:
    """The ``--client`` table (see the module docstring)."""
    with tempfile.TemporaryDirectory() as tmp:
        files = setup(Path(tmp))
        keys = Path(tmp) / "keys" / "s-0"
        broker = start_broker(files, Path(tmp) / "mosquitto.log")
        try:
            with ready_process("the receiver", recv_client, files, str(keys), n) as q:
                send_user, send_sys = send_client(files, keys, 2, n)
                got, user, system = q.get(timeout=120)  # type: ignore[misc]
        finally:
            broker.terminate()
            broker.wait(10)
    recv_user, recv_sys = user / max(got, 1) * 1e6, system / max(got, 1) * 1e6
    print(f"the MQTT client alone: {n:,} messages of 2 bearings at {RATE:,.0f}/s, mosquitto,")
    print(f"mutual TLS, loopback; {got:,} received; CPU µs per message (user + system)")
    print(f"send    {send_user + send_sys:6.1f} ({send_user:.1f} + {send_sys:.1f})")
    print(f"receive {recv_user + recv_sys:6.1f} ({recv_user:.1f} + {recv_sys:.1f})")


def run_pair(
    files: BrokerFiles, keys: Path, k: int, n: int, sender: object, receiver: object
) -> tuple[float, float, int]:
    """Send-side and receive-side CPU µs per message, and messages received."""
    with ready_process("the receiver", receiver, files, str(keys), n) as q:  # type: ignore[arg-type]
        send_us = sender(files, keys, k, n)  # type: ignore[operator]
        got, cpu, rejected = q.get(timeout=120)  # type: ignore[misc]
        if rejected:
            raise RuntimeError(f"the receiver refused {rejected} genuine messages")
    return float(send_us), float(cpu) / max(int(got), 1) * 1e6, int(got)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("n", nargs="?", type=int, help="messages per row (2,000; --client: 3,000)")
    ap.add_argument("--client", action="store_true", help="the MQTT client alone, each side")
    args = ap.parse_args()
    if args.n is not None and args.n < 1:
        ap.error(f"n must be at least 1, got {args.n}")
    if args.client:
        client_only(args.n or 3000)
        return
    n = args.n or 2000
    paho = importlib.util.find_spec("paho") is not None
    with tempfile.TemporaryDirectory() as tmp:
        files = setup(Path(tmp))
        keys = Path(tmp) / "keys" / "s-0"
        broker = start_broker(files, Path(tmp) / "mosquitto.log")
        rows = []
        try:
            for k in (1, 2, 4, 8):
                ours = run_pair(files, keys, k, n, send_ours, recv_ours)
                theirs = run_pair(files, keys, k, n, send_paho, recv_paho) if paho else None
                rows.append((k, ours, theirs))
        finally:
            broker.terminate()
            broker.wait(10)
    print(f"{n:,} messages at {RATE:,.0f}/s a row, mosquitto, mutual TLS, loopback; CPU µs")
    print(
        f"{'bearings/msg':>12} | {'send/msg':>8} {'per bearing':>11} | {'receive/msg':>11} "
        f"{'per bearing':>11} {'received':>8} | {'sign+paho':>9} {'paho+verify':>11}"
    )
    for k, (s, r, got), theirs in rows:
        other = f"{theirs[0]:>9.1f} {theirs[1]:>11.1f}" if theirs else f"{'—':>9} {'—':>11}"
        print(f"{k:>12} | {s:>8.1f} {s / k:>11.1f} | {r:>11.1f} {r / k:>11.1f} {got:>8,} | {other}")
    if not paho:
        print("paho-mqtt is not installed (pip install -e '.[dev]'): no rows beside")


if __name__ == "__main__":
    main()
