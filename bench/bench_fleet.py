"""City scale on a real broker: latency, throughput, scale-out and a forged flood.

    python bench/bench_fleet.py [--quick] [--receiver]

Needs ``mosquitto`` (Debian package) and the ``mqtt`` extra. Everything runs on
127.0.0.1; the broker is started here with mutual TLS and the ACL that
``rfsas broker config`` writes, ``set_tcp_nodelay true``.

1. Frame → advisory latency, lockstep like ``bench_latency.py``: two sensors
   turn one frame each into bearings (DF, hashing), sign version-2
   (pre-authenticated) messages and send them; the backend verifies them,
   associates, triangulates and judges; it signs its assessment as an
   advisory and sends it; the vehicle verifies the advisory. Side by side:
   every hop over direct UDP, and every hop through mosquitto with TLS.
   Goal: p99 ≤ 10 ms through the broker.
2. Sustained signed bearings through the broker into 1 and into 2 backend
   processes (the two own disjoint tile sets of four sensors each):
   8 sensor ids in 2 load processes publish pre-signed version-2 messages at
   a fixed total rate (a minimal MQTT publisher that writes many packets per
   TLS record, standing in for sensors on other machines, so that the cores
   go to what is measured); each backend verifies what its tiles bring.
   Printed beside the rates: CPU µs per message of the backends, mosquitto and
   the load. Goal: ≥ 10,000 messages/s verified with 0 lost, and 2 backends
   ≥ 1.7 × 1 when neither keeps up (16,000/s offered).
3. The receiver's time per forged datagram, in process: version 1 (an
   ECDSA verify each) against version 2 (one HMAC each); and its CPU time per
   valid version-2 message with every check, beside the bare ECDSA verify of
   the same messages (what is left is the receiver's own work); and per
   genuine message that arrives 1.5 s old (``stale``, as at a backend behind
   its clock). ``--receiver`` runs this section alone (no broker).
4. A forged flood at 50,000 datagrams/s on the backend's UDP port while a
   sensor sends at 50 Hz: with version-1 messages (each forgery costs an
   ECDSA verify) and with version 2 required (each forgery costs one HMAC),
   with the listener's default 1 MiB socket buffer and with 4 MiB
   (``udp://…?rcvbuf=4194304``: more time to ride out a scheduling gap).
   Goal: ≥ 99 % of valid messages verified and the link state ok.

Numbers are from one run on a shared 2-core machine; ratios from the same run.
"""

from __future__ import annotations

import contextlib
import getpass
import logging
import multiprocessing as mp
import os
import random
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from multiprocessing.queues import Queue as MpQueue
from pathlib import Path
from typing import Any

import numpy as np
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.hazmat.primitives.asymmetric.utils import encode_dss_signature

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_latency import SENSORS, calibrations, frame_for, vehicle
from udpflood import send_paced

from rfsas_hw.backend.service import BackendService
from rfsas_hw.fleet.advisory import AdvisoryReceiver, AdvisorySink
from rfsas_hw.fleet.broker import BrokerFiles, write_broker_config
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.link import Publisher, Receiver, ReceiverConfig, Signer, TrustedKeys
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.link.latency import LinkState
from rfsas_hw.link.message import SafetyMessage
from rfsas_hw.link.mqtt import open_mqtt
from rfsas_hw.link.mqtt_wire import connect_packet, publish_packet
from rfsas_hw.link.preauth import PreauthKeys, derive_key, seal
from rfsas_hw.link.topics import Route, TopicRouter
from rfsas_hw.link.transport import Transport, open_transport
from rfsas_hw.pipeline import SensorPipeline
from rfsas_hw.privacy.hashing import FixedNonce, MacHasher
from rfsas_hw.records import BearingBatch, Pose

# state changes of the latency watch are expected here (pre-signed messages age)
logging.disable(logging.WARNING)

ORIGIN = SiteOrigin(48.137, 11.575)
ORIGIN_Q = "48.137,11.575"
NONCE = bytes(range(32))
"""The epoch nonce every party of the bench holds (as the authority would hand it out)."""
N_SENSORS = 8
ECDSA_SHA256 = ec.ECDSA(hashes.SHA256())
SENDER_PROCS = 2
LOAD_TICK_S = 0.005
"""How often a load process writes what its sensors have due, seconds."""


class UdpPublishing:
    """Advisories over plain UDP: the route is ignored."""

    def __init__(self, transport: Transport) -> None:
        self.transport = transport

    def publish(self, route: Route, datagram: bytes) -> None:
        self.transport.send(datagram)


class BackendCards:
    def __init__(self, keys: dict[str, ec.EllipticCurvePublicKey]) -> None:
        self.keys = keys

    def backend_key(self, backend_id: str) -> ec.EllipticCurvePublicKey | None:
        return self.keys.get(backend_id)


# --- the broker ---


def setup(root: Path) -> tuple[BrokerFiles, dict[str, KeyStore]]:
    stores: dict[str, KeyStore] = {"auth-0": KeyStore.create(root / "keys/auth-0", "authority")}
    ids = [*SENSORS, *(f"s-{i}" for i in range(N_SENSORS)), "be-0", "be-1"]
    for ident in ids:
        role = "backend" if ident.startswith("be-") else "sensor"
        stores[ident] = KeyStore.create(root / "keys" / ident, role)
        stores["auth-0"].trust.enroll(stores[ident].card)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    files = write_broker_config(
        stores["auth-0"].path,
        root / "broker",
        host="127.0.0.1",
        port=port,
        vehicles=["car-7"],
        run_as=getpass.getuser() if os.geteuid() == 0 else None,
    )
    return files, stores


def start_broker(files: BrokerFiles, log: Path) -> subprocess.Popen[bytes]:
    exe = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
    with log.open("ab") as fh:
        proc = subprocess.Popen([exe, "-c", str(files.conf)], stdout=fh, stderr=fh)
    for _ in range(200):
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", files.port)):
            return proc
        time.sleep(0.05)
    proc.kill()
    raise RuntimeError(f"mosquitto did not start: {log.read_text()}")


# --- 1. latency ---


def latency(n: int, carrier: str, files: BrokerFiles, stores: dict[str, KeyStore]) -> np.ndarray:
    cals = calibrations()
    nonces = FixedNonce(NONCE)
    signers = {sid: stores[sid].signer() for sid in SENSORS}
    trust = TrustedKeys({sid: s.public_key for sid, s in signers.items()})
    be_signer = stores["be-0"].signer()
    cfg = ReceiverConfig(accept_v1=False)
    if carrier == "udp":
        rx = Receiver.listen("udp://127.0.0.1:0", trust, config=cfg, preauth=PreauthKeys(nonces))
        host, port = rx.transport.address  # type: ignore[union-attr]
        pubs = {
            sid: Publisher(
                s, open_transport(f"udp://{host}:{port}", "send"), SENSORS[sid], preauth=nonces
            )
            for sid, s in signers.items()
        }
        car_rx_t = open_transport("udp://127.0.0.1:0", "recv")
        chost, cport = car_rx_t.address  # type: ignore[attr-defined]
        adv_tx: Any = UdpPublishing(open_transport(f"udp://{chost}:{cport}", "send"))
    else:
        rx = Receiver.listen(files.url("be-0"), trust, config=cfg, preauth=PreauthKeys(nonces))
        pubs = {
            sid: Publisher.to_url(files.url(sid, origin=ORIGIN_Q), s, SENSORS[sid], preauth=nonces)
            for sid, s in signers.items()
        }
        car_rx_t = open_mqtt(files.url("car-7", sub="rfsas/v1/vehicle/car-7/advisory"), "recv")
        adv_tx = open_mqtt(files.url("be-0"), "send")
    router = TopicRouter(ORIGIN)
    sink = AdvisorySink(be_signer, adv_tx, router, router.tile_of(0, 0), vehicle_id="car-7")
    car = AdvisoryReceiver(
        BackendCards({"be-0": be_signer.public_key}), car_rx_t, vehicle_id="car-7"
    )
    hasher = MacHasher(nonces)
    pipes = {sid: SensorPipeline(cals[sid], hasher, sid, SENSORS[sid]) for sid in SENSORS}  # type: ignore[arg-type]
    backend = BackendService(sinks=[sink])
    rng = np.random.default_rng(0)
    out = np.empty(n)
    time.sleep(0.3)  # subscriptions settle
    for i in range(n + 30):
        now = time.time_ns()
        t0 = time.perf_counter()
        for sid in SENSORS:
            pubs[sid].on_bearings(pipes[sid].process(frame_for(sid, now, rng)))
        got: list[Any] = []
        while len(got) < len(SENSORS):
            got.extend(rx.receive(timeout=2.0))
        for msg in got:
            backend.on_verified(msg)
        backend.set_vehicle(vehicle(time.time_ns()))
        backend.step()
        advisories: list[Any] = []
        while not advisories:
            advisories = car.receive(timeout=2.0)
        if i >= 30:
            out[i - 30] = time.perf_counter() - t0
    for p in pubs.values():
        p.close()
    rx.close()
    car_rx_t.close()
    if carrier != "udp":
        adv_tx.close()
    assert rx.stats.verified == (n + 30) * len(SENSORS), rx.stats.as_dict()
    return out * 1e3


# --- 2. throughput ---


def sensor_pose(i: int) -> Pose:
    # sensors 3 km apart along a line: each in its own zoom-16 tile
    return Pose(3000.0 * i, 0.0, 0.0)


class LoadPublisher:
    """A load generator's MQTT 5 publisher: CONNECT over mutual TLS, then QoS-0
    PUBLISH packets (the link client's encoder) encoded once and written many
    per TLS record.

    Not a client for sensors (no reconnect, no keepalive, no reading): it stands in
    for sensors on other machines, so that the cores measured go to the broker and
    the backends instead of to the load (paho costs ~170 µs of CPU a publish here).
    """

    def __init__(self, files: BrokerFiles, ident: str) -> None:
        import ssl

        pair = files.client(ident)
        ctx = ssl.create_default_context(cafile=str(files.ca_cert))
        ctx.load_cert_chain(str(pair.cert), str(pair.key))
        raw = socket.create_connection((files.host, files.port), timeout=10)
        raw.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.sock = ctx.wrap_socket(raw, server_hostname=files.host)
        self.sock.sendall(connect_packet(f"load-{ident}-{os.getpid()}", 600))
        ack = self.sock.recv(64)
        if len(ack) < 4 or ack[0] != 0x20 or ack[3] != 0:
            raise RuntimeError(f"{ident}: broker refused the connection: {ack!r}")

    @staticmethod
    def packet(topic: str, payload: bytes) -> bytes:
        """One QoS-0 PUBLISH packet (no properties)."""
        return publish_packet(topic, payload)

    def write(self, packets: bytes) -> None:
        self.sock.sendall(packets)

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.sendall(b"\xe0\x00")
            self.sock.close()


def _sender(
    files_root: str,
    host: str,
    port: int,
    ids: list[str],
    rate: float,
    seconds: float,
    start_at: float,
    q: MpQueue[tuple[int, float]],
) -> None:
    files = BrokerFiles(Path(files_root), host, port, ())
    router = TopicRouter(ORIGIN)
    batches = []
    for ident in ids:
        i = int(ident.split("-")[1])
        signer = KeyStore.open(Path(files_root).parent / "keys" / ident).signer()
        key = derive_key(NONCE, ident)
        count = int(rate * seconds)
        now = time.time_ns()
        epoch = now // 60_000_000_000
        t_ns = np.full(1, epoch * 60_000_000_000 + 1, np.int64)
        b = BearingBatch(
            ident,
            t_ns,
            np.array([10.0]),
            np.array([2.0]),
            np.array([20.0]),
            np.array([6], np.int16),
            np.array([5], np.uint64),
        )
        msgs = [
            seal(signer, SafetyMessage(ident, sensor_pose(i), now // 1000 + k, k, epoch, b), key)
            for k in range(count)
        ]
        topic = router.route(msgs[0], now).topic
        batches.append(
            (LoadPublisher(files, ident), [LoadPublisher.packet(topic, m) for m in msgs])
        )
    while time.time() < start_at:
        time.sleep(0.001)
    sent = 0
    cpu0 = time.process_time()
    t0 = time.perf_counter()
    total = len(batches[0][1])
    k = 0
    while k < total:
        # a write every LOAD_TICK_S: a sensor's packets of that time in one TLS record
        time.sleep(LOAD_TICK_S)
        due = min(total, int((time.perf_counter() - t0) * rate) + 1)
        if due <= k:
            continue
        for tx, packets in batches:
            with contextlib.suppress(OSError):
                tx.write(b"".join(packets[k:due]))
                sent += due - k
        k = due
    cpu = time.process_time() - cpu0
    time.sleep(0.5)
    for tx, _ in batches:
        tx.close()
    q.put((sent, cpu))


def _backend(
    files_root: str,
    host: str,
    port: int,
    ident: str,
    tiles: list[str],
    seconds: float,
    q: MpQueue[tuple[int, int, float, float]],
) -> None:
    files = BrokerFiles(Path(files_root), host, port, ())
    trust = TrustedKeys()
    for i in range(N_SENSORS):
        sid = f"s-{i}"
        trust.enroll(sid, KeyStore.open(Path(files_root).parent / "keys" / sid).card.sign_public)  # type: ignore[arg-type]
    cfg = ReceiverConfig(max_age_s=120.0, check_epoch=False, backlog=1 << 30)
    rx = Receiver.listen(
        files.url(ident, tiles=",".join(tiles), queue="1000000"),
        trust,
        config=cfg,
        preauth=PreauthKeys(FixedNonce(NONCE)),
    )
    first = last = 0.0
    cpu0 = cpu1 = 0.0
    idle_since = time.monotonic()
    deadline = time.monotonic() + seconds + 60
    while time.monotonic() < deadline:
        got = rx.receive(timeout=0.1, max_datagrams=2048)
        if got:
            last = time.monotonic()
            cpu1 = time.process_time()
            if not first:
                first, cpu0 = last, cpu1
            idle_since = last
        elif first and time.monotonic() - idle_since > 2.0:
            break
    rx.close()
    q.put((rx.stats.verified, rx.stats.rejected_total, last - first, cpu1 - cpu0))


def cpu_seconds(pid: int) -> float:
    """User + system CPU time a process has used, seconds (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def throughput(
    files: BrokerFiles, n_backends: int, rate_total: float, seconds: float, broker_pid: int
) -> dict[str, Any]:
    ids = [f"s-{i}" for i in range(N_SENSORS)]
    router = TopicRouter(ORIGIN)
    tiles = {sid: router.tile_of(sensor_pose(i).x_m, 0.0) for i, sid in enumerate(ids)}
    groups = [f"be-{k}" for k in range(n_backends)]
    # a configured plan with the same load on every backend, as an operator who knows
    # the load writes it (rendezvous hashing of only 8 tiles gives a 2/6 split here)
    ordered = sorted(set(tiles.values()))
    plan = {g: ordered[k::n_backends] for k, g in enumerate(groups)}
    ctx = mp.get_context("spawn")
    q_s: MpQueue[tuple[int, float]] = ctx.Queue()
    q_b: MpQueue[tuple[int, int, float, float]] = ctx.Queue()
    root = str(files.root)
    backends = [
        ctx.Process(target=_backend, args=(root, files.host, files.port, g, plan[g], seconds, q_b))
        for g in groups
    ]
    for p in backends:
        p.start()
    time.sleep(2.0)  # backends subscribed
    per_sensor = rate_total / N_SENSORS
    chunks = [ids[k::SENDER_PROCS] for k in range(SENDER_PROCS)]
    start_at = time.time() + 8.0  # every sender has pre-signed its messages
    senders = [
        ctx.Process(
            target=_sender,
            args=(root, files.host, files.port, c, per_sensor, seconds, start_at, q_s),
        )
        for c in chunks
    ]
    for p in senders:
        p.start()
    broker0 = cpu_seconds(broker_pid)
    sends = [q_s.get(timeout=seconds + 120) for _ in senders]
    results = [q_b.get(timeout=seconds + 120) for _ in backends]
    broker_cpu = cpu_seconds(broker_pid) - broker0
    for p in senders + backends:
        p.join(10)
    sent = sum(r[0] for r in sends)
    verified = sum(r[0] for r in results)
    span = max(r[2] for r in results) or float("nan")
    return {
        "backends": n_backends,
        "offered": rate_total,
        "sent": sent,
        "verified": verified,
        "lost": sent - verified,
        "rate": verified / span,
        "rejected": sum(r[1] for r in results),
        "backend_us": 1e6 * sum(r[3] for r in results) / max(verified, 1),
        "broker_us": 1e6 * broker_cpu / max(sent, 1),
        "load_us": 1e6 * sum(r[1] for r in sends) / max(sent, 1),
    }


# --- 3. flood ---

SENSOR_KEY = 0x5EED_CAFE


def _valid_sensor(port: int, hz: float, seconds: float, q: MpQueue[int]) -> None:
    signer = Signer("rsu-1", ec.derive_private_key(SENSOR_KEY, ec.SECP256R1()))
    pub = Publisher(
        signer,
        open_transport(f"udp://127.0.0.1:{port}", "send"),
        Pose(0, 0, 0),
        preauth=FixedNonce(NONCE),
    )
    rng = np.random.default_rng(1)
    n = int(hz * seconds)
    t0 = time.perf_counter()
    for k in range(n):
        while time.perf_counter() < t0 + k / hz:
            time.sleep(0.0005)
        b = BearingBatch(
            "rsu-1",
            np.array([time.time_ns()]),
            rng.uniform(0, 360, 1),
            np.array([2.0]),
            np.array([20.0]),
            np.array([6], np.int16),
            np.array([9], np.uint64),
        )
        pub.on_bearings(b)
    pub.close()
    q.put(pub.stats.messages)


def _forger(port: int, rate: int, seconds: float, version: int, q: MpQueue[int]) -> None:
    rng = random.Random(7)
    signer = Signer("rsu-1", ec.derive_private_key(SENSOR_KEY, ec.SECP256R1()))
    now = time.time_ns()
    b = BearingBatch(
        "rsu-1",
        np.array([now]),
        np.array([1.0]),
        np.array([2.0]),
        np.array([20.0]),
        np.array([6], np.int16),
        np.array([9], np.uint64),
    )
    msg = SafetyMessage("rsu-1", Pose(0, 0, 0), now // 1000, 1, now // 60_000_000_000, b)
    if version == 1:
        good = signer.encode(msg)
        payloads = [good[:-64] + rng.randbytes(64) for _ in range(512)]
    else:  # the outsider has no nonce: a random key, so a wrong tag
        good = seal(signer, msg, rng.randbytes(32))
        payloads = [good[:-72] + rng.randbytes(72) for _ in range(512)]
    q.put(send_paced(payloads, port, rate, seconds))


def flood(version: int, rate: int, seconds: float, rcvbuf: int = 1 << 20) -> dict[str, Any]:
    key = ec.derive_private_key(SENSOR_KEY, ec.SECP256R1())
    cfg = ReceiverConfig(accept_v1=version == 1)
    rx = Receiver.listen(
        f"udp://127.0.0.1:0?rcvbuf={rcvbuf}",
        TrustedKeys({"rsu-1": key.public_key()}),
        config=cfg,
        preauth=PreauthKeys(FixedNonce(NONCE)),
    )
    port = rx.transport.address[1]  # type: ignore[union-attr]
    ctx = mp.get_context("spawn")
    q_s: MpQueue[int] = ctx.Queue()
    q_f: MpQueue[int] = ctx.Queue()
    procs = [ctx.Process(target=_valid_sensor, args=(port, 50.0, seconds, q_s))]
    if rate:
        procs.append(ctx.Process(target=_forger, args=(port, rate, seconds, version, q_f)))
    states: list[str] = []
    for p in procs:
        p.start()
    while procs[0].is_alive():
        rx.receive(timeout=0.05)
        snap = rx.latency.snapshot(time.time_ns()).get("rsu-1")
        if snap is not None:
            states.append(snap.state.value)
    for _ in range(5):
        rx.receive(timeout=0.05)
    for p in procs:
        p.join(10)
    rx.close()
    sent = q_s.get(timeout=10)
    worst = "ok" if all(s == LinkState.OK.value for s in states) else ",".join(sorted(set(states)))
    return {
        "version": version,
        "junk_rate": q_f.get(timeout=10) if rate else 0,
        "valid_sent": sent,
        "verified": rx.stats.verified,
        "share": rx.stats.verified / sent,
        "state": worst,
        "rejected": dict(rx.stats.rejected),
    }


def reject_cost(n: int = 2000) -> dict[str, float]:
    """µs a receiver spends on one forged datagram from an enrolled sender id, in process."""
    signer = Signer("rsu-1", ec.derive_private_key(SENSOR_KEY, ec.SECP256R1()))
    trust = TrustedKeys({"rsu-1": signer.public_key})
    now = time.time_ns()
    b = BearingBatch(
        "rsu-1",
        np.array([now]),
        np.array([1.0]),
        np.array([2.0]),
        np.array([20.0]),
        np.array([6], np.int16),
        np.array([9], np.uint64),
    )
    out = {}
    for version in (1, 2):
        cfg = ReceiverConfig(accept_v1=version == 1, sender_rate_hz=1e9, sender_burst=1e9)
        rx = Receiver(trust, config=cfg, preauth=PreauthKeys(FixedNonce(NONCE)))
        forged = []
        for k in range(n if version == 2 else n // 10):
            msg = SafetyMessage("rsu-1", Pose(0, 0, 0), now // 1000, k, now // 60_000_000_000, b)
            raw = signer.encode(msg) if version == 1 else seal(signer, msg, os.urandom(32))
            forged.append(raw[:-8] + os.urandom(8))
        t0 = time.perf_counter()
        for d in forged:
            rx.feed(d, now)
        out[f"v{version}"] = (time.perf_counter() - t0) / len(forged) * 1e6
        assert rx.stats.verified == 0
    return out


class Queued(Transport):
    """Hands a receiver datagrams that are already there (no socket)."""

    def __init__(self, items: list[tuple[bytes, str | None]]) -> None:
        self.items = items[::-1]

    def send(self, datagram: bytes) -> None:
        raise NotImplementedError("receive only")

    def recv(self, timeout: float | None = None) -> bytes | None:
        got = self.recv_from(timeout)
        return None if got is None else got[0]

    def recv_from(self, timeout: float | None = None) -> tuple[bytes, str | None] | None:
        return self.items.pop() if self.items else None

    def close(self) -> None:
        pass


def _sealed(
    n: int, now: int, age_us: int = 0
) -> tuple[TrustedKeys, list[tuple[bytes, str, ec.EllipticCurvePublicKey]]]:
    """``n`` genuine version-2 messages of 4 senders generated ``age_us`` before ``now``
    (UTC ns; sequence numbers and times apart), with their topics and senders' keys."""
    signers = [
        Signer(f"s-{i}", ec.derive_private_key(SENSOR_KEY + i, ec.SECP256R1())) for i in range(4)
    ]
    trust = TrustedKeys({s.sender_id: s.public_key for s in signers})
    router = TopicRouter(ORIGIN)
    epoch = now // 60_000_000_000
    items: list[tuple[bytes, str, ec.EllipticCurvePublicKey]] = []
    for k in range(n):
        signer = signers[k % len(signers)]
        sid = signer.sender_id
        b = BearingBatch(
            sid,
            np.array([epoch * 60_000_000_000 + 1]),
            np.array([10.0]),
            np.array([2.0]),
            np.array([20.0]),
            np.array([6], np.int16),
            np.array([5], np.uint64),
        )
        msg = SafetyMessage(sid, sensor_pose(k % 4), now // 1000 - age_us + k, k, epoch, b)
        raw = seal(signer, msg, derive_key(NONCE, sid))
        items.append((raw, router.route(raw, now).topic, signer.public_key))
    return trust, items


def accept_cost(n: int = 2000, rounds: int = 3) -> dict[str, float]:
    """µs a receiver spends on one valid version-2 message with every check, one at
    a time (``feed_from``) and in batches as a backend takes them (``receive``),
    beside the bare ECDSA P-256 verify of the same messages (in process, CPU time;
    the three alternate ``rounds`` times and the fastest round of each counts)."""
    now = time.time_ns()
    trust, items = _sealed(n, now)
    bare = [(pub, der_of(raw), raw[: -8 - 64]) for raw, _, pub in items]
    best = {"one": float("inf"), "batch": float("inf"), "verify": float("inf")}
    cfg = ReceiverConfig(max_age_s=120.0, check_epoch=False, backlog=1 << 30)
    for _ in range(rounds):
        rx = Receiver(trust, config=cfg, preauth=PreauthKeys(FixedNonce(NONCE)))
        t0 = time.process_time()
        for raw, topic, _ in items:
            rx.feed_from(raw, topic, now)
        t1 = time.process_time()
        for pub, der, body in bare:
            pub.verify(der, body, ECDSA_SHA256)
        t2 = time.process_time()
        queued = Queued([(raw, topic) for raw, topic, _ in items])
        batched = Receiver(
            trust, config=cfg, preauth=PreauthKeys(FixedNonce(NONCE)), transport=queued
        )
        t3 = time.process_time()
        got = 0
        while queued.items:
            got += len(batched.receive(0, max_datagrams=2048))
        t4 = time.process_time()
        assert rx.stats.verified == n == got, (rx.stats.as_dict(), got)
        best["one"] = min(best["one"], (t1 - t0) / n * 1e6)
        best["verify"] = min(best["verify"], (t2 - t1) / n * 1e6)
        best["batch"] = min(best["batch"], (t4 - t3) / n * 1e6)
    return best


def stale_cost(n: int = 2000, rounds: int = 3) -> dict[str, float]:
    """CPU µs a receiver spends refusing one genuine version-2 message that arrives
    1.5 s after it was generated (``stale``: a backend behind its clock), in batches
    as a backend takes them (``receive``) and one at a time (``feed_from``); the
    fastest of ``rounds``."""
    now = time.time_ns()
    trust, items = _sealed(n, now, age_us=1_500_000)
    cfg = ReceiverConfig(check_epoch=False, backlog=1 << 30)
    best = {"one": float("inf"), "batch": float("inf")}
    for _ in range(rounds):
        rx = Receiver(trust, config=cfg, preauth=PreauthKeys(FixedNonce(NONCE)), clock=lambda: now)
        t0 = time.process_time()
        for raw, topic, _ in items:
            rx.feed_from(raw, topic, now)
        t1 = time.process_time()
        queued = Queued([(raw, topic) for raw, topic, _ in items])
        batched = Receiver(
            trust,
            config=cfg,
            preauth=PreauthKeys(FixedNonce(NONCE)),
            transport=queued,
            clock=lambda: now,
        )
        t2 = time.process_time()
        while queued.items:
            batched.receive(0, max_datagrams=2048)
        t3 = time.process_time()
        assert rx.stats.rejected["stale"] == n == batched.stats.rejected["stale"]
        best["one"] = min(best["one"], (t1 - t0) / n * 1e6)
        best["batch"] = min(best["batch"], (t3 - t2) / n * 1e6)
    return best


def der_of(raw: bytes) -> bytes:
    """The DER signature of a version-2 datagram, as ``cryptography`` takes it."""
    sig = raw[-8 - 64 : -8]
    return encode_dss_signature(int.from_bytes(sig[:32], "big"), int.from_bytes(sig[32:], "big"))


def receiver_costs(quick: bool) -> None:
    """Section 3: the receiver's CPU per datagram, in process."""
    cost = reject_cost()
    print("3. Receiver time per datagram (in process, no socket)")
    for v, label in (("v1", "version 1: ECDSA verify"), ("v2", "version 2: HMAC tag first")):
        print(f"{label:<34} {cost[v]:8.1f} µs  → {1e6 / cost[v]:>9,.0f} forgeries/s per core")
    print(f"version 1 / version 2: {cost['v1'] / cost['v2']:.1f}×")
    valid = accept_cost(500 if quick else 2000)
    print(
        f"a valid version-2 message, every check (CPU µs; bare ECDSA verify {valid['verify']:.1f})"
    )
    for key, label in (("one", "one at a time (feed_from)"), ("batch", "in batches (receive)")):
        rest = valid[key] - valid["verify"]
        print(f"  {label:<32} {valid[key]:8.1f} µs, {rest:.1f} µs besides the verify")
    stale = stale_cost(500 if quick else 2000)
    print("a genuine version-2 message 1.5 s old, refused as stale (CPU µs)")
    for key, label in (("one", "one at a time (feed_from)"), ("batch", "in batches (receive)")):
        print(f"  {label:<32} {stale[key]:8.1f} µs")
    print()


def main() -> None:
    quick = "--quick" in sys.argv
    if "--receiver" in sys.argv:  # section 3 alone: no broker needed
        receiver_costs(quick)
        return
    if shutil.which("mosquitto") is None and not Path("/usr/sbin/mosquitto").exists():
        sys.exit("mosquitto is not installed (Debian package mosquitto)")
    root = Path(tempfile.mkdtemp(prefix="rfsas-fleet-"))
    files, stores = setup(root)
    broker = start_broker(files, root / "mosquitto.log")
    try:
        n = 300 if quick else 1000
        print(f"1. Frame → advisory, {n} frames × 2 sensors, lockstep, version-2 messages")
        print(f"{'carrier':<32} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8}")
        for carrier, label in (("udp", "direct UDP"), ("mqtts", "mosquitto, mutual TLS, QoS 0")):
            t = latency(n, carrier, files, stores)
            p50, p99 = np.percentile(t, [50, 99])
            print(f"{label:<32} {p50:8.2f} {p99:8.2f} {t.max():8.1f}")
        print()
        seconds = 3.0 if quick else 5.0
        print(f"2. Signed bearings through mosquitto (TLS) into backend processes, {seconds:g} s")
        print(
            f"{'backends':>8} {'offered/s':>10} {'sent':>8} {'verified':>9} {'lost':>6} "
            f"{'verified/s':>11}   CPU µs a message: {'backends':>8} {'broker':>6} {'load':>5}"
        )
        runs = {}
        for rate in (4_000, 10_000, 16_000):
            for k in (1, 2):
                r = throughput(files, k, rate, seconds, broker.pid)
                runs[(rate, k)] = r
                print(
                    f"{k:>8} {rate:>10,} {r['sent']:>8,} {r['verified']:>9,} {r['lost']:>6,} "
                    f"{r['rate']:>11,.0f}   {'':>17} {r['backend_us']:>8.0f} "
                    f"{r['broker_us']:>6.0f} {r['load_us']:>5.0f}"
                )
        ratio = runs[(16_000, 2)]["rate"] / runs[(16_000, 1)]["rate"]
        print(f"2 backends / 1 backend at 16,000/s offered (more than both take): {ratio:.2f}×")
        r = runs[(16_000, 2)]
        share = (r["broker_us"] + r["load_us"]) * r["rate"] / 1e6
        print(
            f"  at that rate the broker and the load use {share:.2f} of the 2 cores: "
            f"the most 2 backends can have is {2 - share:.2f} cores against 1 core for one"
        )
        print()
    finally:
        broker.terminate()
        broker.wait(5)
    seconds = 2.0 if quick else 3.0
    receiver_costs(quick)
    print(f"4. Forged flood at 50,000/s on UDP, sensor at 50 Hz, {seconds:g} s")
    print(f"{'messages':<34} {'junk/s':>8} {'valid':>6} {'verified':>9} {'share':>7} {'state':>8}")
    for version, rcvbuf, label in (
        (1, 1 << 20, "version 1, 1 MiB socket buffer"),
        (2, 1 << 20, "version 2 required, 1 MiB buffer"),
        (2, 4 << 20, "version 2 required, 4 MiB buffer"),
    ):
        r = flood(version, 50_000, seconds, rcvbuf)
        print(
            f"{label:<34} {r['junk_rate']:>8,} {r['valid_sent']:>6} {r['verified']:>9} "
            f"{100 * r['share']:>6.1f}% {r['state']:>8}"
        )
    shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
