"""CPU per received message: the link's own MQTT 5 client beside gmqtt and paho-mqtt.

    python bench/bench_mqtt_client.py [N]

Needs ``mosquitto`` (Debian package) and the ``bench`` extra (gmqtt; paho-mqtt
comes with ``dev``). Everything runs on 127.0.0.1: mosquitto is started with
the mutual TLS and ACL that ``rfsas broker config`` writes (as in
``bench_fleet.py``). For each client in turn a child process connects as the
backend ``be-0`` with its certificate, subscribes to every bearing topic and
counts N messages (default 20,000) of 180 bytes, which a load publisher
(``bench_fleet.LoadPublisher``: pre-encoded QoS-0 packets, many per TLS
record) sends as sensor ``s-0`` at 5,000 a second:

- rfsas-hw: ``open_mqtt(url, "recv")`` and ``recv_many`` (what the backend's
  receiver runs);
- gmqtt 0.8 (asyncio), MQTT 5, an ``on_message`` callback;
- paho-mqtt 2 with MQTT 5, ``loop_start`` (its network thread) and an
  ``on_message`` callback.

CPU is the receiving process's (every thread), from subscribed to the last
message, divided by the messages received; the clients do nothing with a
message but count it. Numbers are from one run on a shared machine; ratios
from the same run.
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib.util
import multiprocessing as mp
import os
import ssl
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from multiprocessing.queues import Queue as MpQueue
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_fleet import LoadPublisher, start_broker

from rfsas_hw.fleet.broker import BrokerFiles, write_broker_config
from rfsas_hw.link.keys import KeyStore

TOPIC = "rfsas/v1/bearing/s-0/1202120"
FILTER = "rfsas/v1/bearing/#"
PAYLOAD = bytes(range(180))
RATE = 5000.0
TICK_S = 0.01
IDLE_S = 3.0
"""A client that hears nothing for this long after the first message is done."""


def setup(root: Path) -> BrokerFiles:
    auth = KeyStore.create(root / "keys" / "auth-0", "authority")
    for ident, role in (("s-0", "sensor"), ("be-0", "backend")):
        auth.trust.enroll(KeyStore.create(root / "keys" / ident, role).card)
    import getpass
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    return write_broker_config(
        auth.path,
        root / "broker",
        host="127.0.0.1",
        port=port,
        run_as=getpass.getuser() if os.geteuid() == 0 else None,
    )


def _tls(files: BrokerFiles) -> ssl.SSLContext:
    pair = files.client("be-0")
    ctx = ssl.create_default_context(cafile=str(files.ca_cert))
    ctx.load_cert_chain(str(pair.cert), str(pair.key))
    return ctx


def _ours(files: BrokerFiles, n: int, q: MpQueue[object]) -> None:
    from rfsas_hw.link.mqtt import open_mqtt

    transport = open_mqtt(files.url("be-0", sub=FILTER), "recv")
    time.sleep(0.5)  # the subscription settles
    q.put("ready")
    t0 = time.process_time()
    got = 0
    while got < n:
        batch = transport.recv_many(timeout=IDLE_S if got else 60.0)
        if not batch:
            break
        got += len(batch)
    q.put((got, time.process_time() - t0))
    transport.close()


def paho_receive(
    files: BrokerFiles,
    n: int,
    q: MpQueue[object],
    client_id: str = "bench-paho",
    check: Callable[[bytes], object] | None = None,
    tail: tuple[object, ...] = (),
) -> None:
    """Receive up to ``n`` messages of :data:`FILTER` with paho-mqtt (mutual TLS), each
    payload passed to ``check`` if given; put "ready" once subscribed, then (received, CPU
    seconds, *tail) on ``q``. Stops after ``n`` or when nothing arrives for :data:`IDLE_S`."""
    import paho.mqtt.client as mqtt

    pair = files.client("be-0")
    done = threading.Event()
    subscribed = threading.Event()
    count = [0]

    def on_message(_c: object, _u: object, message: mqtt.MQTTMessage) -> None:
        if check is not None:
            check(message.payload)
        count[0] += 1
        if count[0] >= n:
            done.set()

    client = mqtt.Client(
        mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, protocol=mqtt.MQTTv5
    )
    client.tls_set(str(files.ca_cert), str(pair.cert), str(pair.key))
    client.on_connect = lambda c, *_: c.subscribe(FILTER, qos=0)
    client.on_subscribe = lambda *_: subscribed.set()
    client.on_message = on_message
    client.connect(files.host, files.port, keepalive=30)
    client.loop_start()
    if not subscribed.wait(20):
        raise RuntimeError("paho-mqtt did not subscribe within 20 s")
    q.put("ready")
    t0 = time.process_time()
    last = -1
    while not done.wait(IDLE_S if count[0] else 60.0) and count[0] != last:
        last = count[0]
    q.put((count[0], time.process_time() - t0, *tail))
    client.disconnect()
    client.loop_stop()


def _paho(files: BrokerFiles, n: int, q: MpQueue[object]) -> None:
    paho_receive(files, n, q)


def _gmqtt(files: BrokerFiles, n: int, q: MpQueue[object]) -> None:
    import gmqtt

    async def run() -> None:
        done = asyncio.Event()
        count = [0]

        def on_message(*_: object) -> int:
            count[0] += 1
            if count[0] >= n:
                done.set()
            return 0

        client = gmqtt.Client("bench-gmqtt")
        client.on_message = on_message
        await client.connect(files.host, files.port, ssl=_tls(files), version=5)
        client.subscribe(FILTER, qos=0)
        await asyncio.sleep(0.5)  # the subscription settles
        q.put("ready")
        t0 = time.process_time()
        last = -1
        while count[0] < n and count[0] != last:
            last = count[0]
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(done.wait(), IDLE_S if count[0] else 60.0)
        q.put((count[0], time.process_time() - t0))
        await client.disconnect()

    asyncio.run(run())


NEEDS = {"gmqtt 0.8 (MQTT 5)": ("gmqtt", "bench"), "paho-mqtt 2 (MQTT 5)": ("paho", "dev")}
"""The import each other client needs, and the extra that installs it."""

CLIENTS = {
    "rfsas-hw (own MQTT 5)": _ours,
    "gmqtt 0.8 (MQTT 5)": _gmqtt,
    "paho-mqtt 2 (MQTT 5)": _paho,
}


@contextlib.contextmanager
def ready_process(
    name: str, target: Callable[..., None], *args: object
) -> Iterator[MpQueue[object]]:
    """A spawned process running ``target(*args, queue)`` that puts "ready" on the queue
    first; the queue, to read its results. When the block ends the process is joined
    (killed after 10 s) and the queue closed.

    Raises:
        RuntimeError: the process did not say "ready" within 60 s.
    """
    ctx = mp.get_context("spawn")
    q: MpQueue[object] = ctx.Queue()
    proc = ctx.Process(target=target, args=(*args, q), daemon=True)
    proc.start()
    try:
        if q.get(timeout=60) != "ready":
            raise RuntimeError(f"{name}: did not get ready")
        yield q
    finally:
        proc.join(10)
        if proc.is_alive():
            proc.kill()
            proc.join(5)
        q.close()


def measure(name: str, files: BrokerFiles, n: int) -> tuple[int, float]:
    """Messages the client received and its CPU seconds for them."""
    with ready_process(name, CLIENTS[name], files, n) as q:
        load = LoadPublisher(files, "s-0")
        packet = LoadPublisher.packet(TOPIC, PAYLOAD)
        per_tick = int(RATE * TICK_S)
        start = time.monotonic()
        sent = 0
        while sent < n:
            k = min(per_tick, n - sent)
            load.write(packet * k)
            sent += k
            pause = start + sent / RATE - time.monotonic()
            if pause > 0:
                time.sleep(pause)
        load.close()
        got, cpu = q.get(timeout=120)  # type: ignore[misc]
    return int(got), float(cpu)


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 20_000
    with tempfile.TemporaryDirectory() as tmp:
        files = setup(Path(tmp))
        broker = start_broker(files, Path(tmp) / "mosquitto.log")
        rows: list[tuple[str, int, float]] = []
        missing: list[str] = []
        try:
            for name in CLIENTS:
                module, extra = NEEDS.get(name, ("rfsas_hw", ""))
                if importlib.util.find_spec(module) is None:
                    missing.append(f"{name}: NOT installed (pip install -e '.[{extra}]')")
                    continue
                rows.append((name, *measure(name, files, n)))
        finally:
            broker.terminate()
            broker.wait(10)
    print(f"{n:,} messages of {len(PAYLOAD)} B at {RATE:,.0f}/s, mosquitto, mutual TLS, loopback")
    print(f"{'client':<24} {'received':>9} {'CPU µs/message':>15} {'× own':>7}")
    own = rows[0][2] / max(rows[0][1], 1)
    for name, got, cpu in rows:
        per = cpu / max(got, 1)
        print(f"{name:<24} {got:>9,} {per * 1e6:>15.1f} {per / own:>7.2f}")
    for line in missing:
        print(line)


if __name__ == "__main__":
    main()
