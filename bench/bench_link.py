"""The secure link under load: hashing, signing, verifying, and a junk flood on loopback.

    python bench/bench_link.py [--quick]

1. MAC hashing: ``MacHasher.hash_batch`` next to the per-frame ``hmac.new`` loop
   a user would write, on frames from a realistic population (many frames per
   MAC) and on all-distinct MACs (the cache cannot help).
2. Messages: signing and full verification per second, next to the bare
   ``cryptography`` ECDSA P-256 sign/verify of the same bytes (the cost of our
   framing and checks), and how fast junk is rejected before any cryptography.
3. Flood: a sensor process sends signed messages at 50 Hz while a second
   process sends junk at 50,000 datagrams/s to the same UDP port on 127.0.0.1;
   the receiver reports how many valid messages it verified, their age p50/p99
   and its latency alarm. Two kinds of junk: random bytes and malformed
   headers (rejected before the signature check), and forged signatures under
   an enrolled sender id (each costs an ECDSA verify: the expensive attack).
   Bounded: a few seconds and at most 50,000·seconds junk datagrams per run.

Ratios are from this one run on a possibly shared machine.
"""

from __future__ import annotations

import hashlib
import hmac
import multiprocessing as mp
import os
import random
import socket
import sys
import time
from collections.abc import Callable
from multiprocessing.queues import Queue as MpQueue
from typing import Any

import numpy as np
from benchtime import timed
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.asymmetric import ec
from udpflood import send_paced

from rfsas_hw.link import Publisher, Receiver, ReceiverConfig, Signer, TrustedKeys, open_transport
from rfsas_hw.link.latency import LinkState
from rfsas_hw.link.message import SafetyMessage
from rfsas_hw.privacy import FixedNonce, MacHasher
from rfsas_hw.records import BearingBatch, Pose

NS = 1_000_000_000
SENSOR_KEY = 0x5EED_CAFE
BUDGET_MS = 100.0


def table(title: str, rows: list[tuple[str, int, float]], unit: str) -> None:
    ours = rows[0][1] / rows[0][2]
    print(title)
    print(f"{'method':<52} {'count':>10} {'time (ms)':>10} {unit + '/s':>14} {'rfsas-hw is':>12}")
    for name, count, secs in rows:
        rate = count / secs
        print(f"{name:<52} {count:>10,} {secs * 1e3:>10.1f} {rate:>14,.0f} {ours / rate:>11.2f}×")
    print()


def bench_hashing(n: int) -> None:
    rng = np.random.default_rng(0)
    nonce = rng.bytes(32)
    population = rng.integers(0, 1 << 48, 5_000, dtype=np.uint64)
    macs = population[rng.integers(0, len(population), n)]
    t_ns = np.sort(rng.integers(1_763_800_000 * NS, 1_763_800_120 * NS, n)).astype(np.int64)
    distinct = rng.choice(1 << 40, size=n // 5, replace=False).astype(np.uint64)

    def ours(m: np.ndarray, t: np.ndarray) -> Callable[[], object]:
        return lambda: MacHasher(FixedNonce(nonce)).hash_batch(m, t)

    def naive(m: np.ndarray) -> Callable[[], object]:
        ints = m.tolist()
        return lambda: [
            int.from_bytes(
                hmac.new(nonce, x.to_bytes(6, "big"), hashlib.sha256).digest()[:8], "big"
            )
            for x in ints
        ]

    k = min(n, 200_000)
    table(
        f"MAC hashing, {n:,} frames from 5,000 devices over 2 epochs",
        [
            ("rfsas-hw MacHasher.hash_batch (fresh cache)", n, timed(ours(macs, t_ns))),
            ("per-frame hmac.new(nonce, mac, sha256) loop", k, timed(naive(macs[:k]), 1)),
        ],
        "hashes",
    )
    t_d = np.full(len(distinct), t_ns[0])
    table(
        f"MAC hashing, {len(distinct):,} distinct MACs (no cache hits)",
        [
            ("rfsas-hw MacHasher.hash_batch", len(distinct), timed(ours(distinct, t_d))),
            ("per-frame hmac.new loop", len(distinct), timed(naive(distinct), 1)),
        ],
        "hashes",
    )


def make_message(seq: int, n: int, t_ns: int) -> SafetyMessage:
    rng = np.random.default_rng(seq)
    batch = BearingBatch(
        sensor_id="rsu-1",
        t_ns=np.full(n, t_ns, np.int64),
        azimuth_deg=rng.uniform(0, 360, n),
        sigma_deg=rng.uniform(1, 10, n),
        snr_db=rng.uniform(5, 40, n),
        channel=np.full(n, 6, np.int16),
        emitter=rng.integers(0, 2**63, n, dtype=np.uint64),
    )
    return SafetyMessage("rsu-1", Pose(10, 20, 90), t_ns // 1000, seq, t_ns // (60 * NS), batch)


def bench_messages(n: int) -> None:
    key = ec.derive_private_key(SENSOR_KEY, ec.SECP256R1())
    signer = Signer("rsu-1", key)
    now = time.time_ns()
    msgs = [make_message(i, 20, now) for i in range(n)]
    datagrams = [signer.encode(m) for m in msgs]
    bodies = [d[:-64] for d in datagrams]
    der = [key.sign(b, ec.ECDSA(hashes.SHA256())) for b in bodies]
    pub = key.public_key()
    trust = TrustedKeys({"rsu-1": pub})

    def verify_all() -> None:
        cfg = ReceiverConfig(max_age_s=600.0, replay_capacity=2 * n)
        rx = Receiver(trust, config=cfg, clock=lambda: now)
        for d in datagrams:
            rx.feed(d, now)
        assert rx.stats.verified == n, rx.stats

    def raw_verify() -> None:
        for b, s in zip(bodies, der, strict=True):
            pub.verify(s, b, ec.ECDSA(hashes.SHA256()))

    size = len(datagrams[0])
    table(
        f"Signing, {n:,} messages of 20 bearings ({size} bytes)",
        [
            (
                "rfsas-hw Signer.encode (pack + sign)",
                n,
                timed(lambda: [signer.encode(m) for m in msgs], 1),
            ),
            (
                "cryptography ECDSA P-256 sign only",
                n,
                timed(lambda: [key.sign(b, ec.ECDSA(hashes.SHA256())) for b in bodies], 1),
            ),
        ],
        "messages",
    )
    table(
        f"Verifying, {n:,} messages of 20 bearings",
        [
            ("rfsas-hw Receiver.feed (all checks + decode)", n, timed(verify_all, 1)),
            ("cryptography ECDSA P-256 verify only", n, timed(raw_verify, 1)),
        ],
        "messages",
    )
    rng = random.Random(1)
    junk = [rng.randbytes(rng.randrange(1, 300)) for _ in range(50_000)]
    junk += [b"RF\x01\x01\x00\x05rsu-9" + rng.randbytes(200) for _ in range(50_000)]
    forged = [d[:-64] + rng.randbytes(64) for d in datagrams]

    def reject(items: list[bytes]) -> Callable[[], None]:
        def run() -> None:
            rx = Receiver(trust, clock=lambda: now)
            for d in items:
                rx.feed(d, now)
            assert rx.stats.verified == 0

        return run

    table(
        "Rejecting junk",
        [
            ("junk / unknown sender (no cryptography)", len(junk), timed(reject(junk), 1)),
            (
                "forged signature, enrolled sender (ECDSA verify)",
                len(forged),
                timed(reject(forged), 1),
            ),
        ],
        "rejections",
    )


def _sensor(port: int, hz: float, seconds: float, out: MpQueue[int]) -> None:
    signer = Signer("rsu-1", ec.derive_private_key(SENSOR_KEY, ec.SECP256R1()))
    pub = Publisher(signer, open_transport(f"udp://127.0.0.1:{port}", "send"), Pose(10, 20, 90))
    rng = np.random.default_rng(1)
    n = int(hz * seconds)
    t0 = time.perf_counter()
    for i in range(n):
        delay = t0 + i / hz - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        now = time.time_ns()
        pub.on_bearings(
            BearingBatch(
                "rsu-1",
                np.full(10, now, np.int64),
                rng.uniform(0, 360, 10),
                np.full(10, 3.0),
                np.full(10, 20.0),
                np.full(10, 6, np.int16),
                rng.integers(0, 2**63, 10, dtype=np.uint64),
            )
        )
    pub.close()
    out.put(pub.stats.messages)


def _flood(port: int, rate: int, seconds: float, kind: str, out: MpQueue[int]) -> None:
    rng = random.Random(7)
    if kind == "forged":
        signer = Signer("rsu-1", ec.derive_private_key(SENSOR_KEY, ec.SECP256R1()))
        good = signer.encode(make_message(0, 10, time.time_ns()))
        payloads = [good[:-64] + rng.randbytes(64) for _ in range(512)]
    else:
        payloads = [rng.randbytes(rng.randrange(1, 400)) for _ in range(256)]
        payloads += [
            b"RF\x01\x01\x00\x05rsu-1" + rng.randbytes(rng.randrange(0, 600)) for _ in range(256)
        ]
    out.put(send_paced(payloads, port, rate, seconds))


def flood(kind: str, rate: int, seconds: float, hz: float = 50.0) -> dict[str, Any]:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    sock.close()
    key = ec.derive_private_key(SENSOR_KEY, ec.SECP256R1())
    rx = Receiver.listen(f"udp://127.0.0.1:{port}", TrustedKeys({"rsu-1": key.public_key()}))
    ctx = mp.get_context("spawn")
    q_sensor: MpQueue[int] = ctx.Queue()
    q_flood: MpQueue[int] = ctx.Queue()
    procs = [ctx.Process(target=_sensor, args=(port, hz, seconds, q_sensor))]
    if rate > 0:
        procs.append(ctx.Process(target=_flood, args=(port, rate, seconds, kind, q_flood)))
    ages: list[float] = []
    alarms: list[str] = []
    running = [True]

    def note(sender: str, old: LinkState, new: LinkState) -> None:
        if running[0]:  # the silence after the sensor stops is not part of the run
            alarms.append(f"{old.value}->{new.value}")

    rx.latency.add_callback(note)
    for p in procs:
        p.start()
    deadline = time.monotonic() + seconds + 30
    while procs[0].is_alive() and time.monotonic() < deadline:
        ages += [m.age_s * 1e3 for m in rx.receive(timeout=0.05)]
    ages += [m.age_s * 1e3 for m in rx.receive(timeout=0.05)]
    state = rx.latency.snapshot(time.time_ns())["rsu-1"].state.value
    running[0] = False
    for _ in range(10):  # drain what is still queued
        ages += [m.age_s * 1e3 for m in rx.receive(timeout=0.05)]
    for p in procs:
        p.join(5)
    rx.close()
    sent_valid = q_sensor.get(timeout=5)
    achieved = q_flood.get(timeout=5) if rate > 0 else 0
    arr = np.asarray(ages) if ages else np.asarray([np.nan])
    return {
        "kind": kind if rate else "none",
        "junk_sent": int(rate * seconds),
        "junk_rate": achieved,
        "valid_sent": sent_valid,
        "verified": rx.stats.verified,
        "seen": rx.stats.datagrams,
        "rejected": rx.stats.rejected_total,
        "shed": rx.stats.rejected["overload"],
        "state": state,
        "p50": float(np.percentile(arr, 50)),
        "p99": float(np.percentile(arr, 99)),
        "max": float(np.max(arr)),
        "alarms": ",".join(alarms) or "none",
    }


COLUMNS = [
    ("flood", "kind", "<8", ""),
    ("junk sent", "junk_sent", ">10", ","),
    ("junk/s", "junk_rate", ">7", ","),
    ("seen", "seen", ">8", ","),
    ("shed", "shed", ">7", ","),
    ("valid sent", "valid_sent", ">10", ","),
    ("verified", "verified", ">8", ","),
    ("age p50 ms", "p50", ">10", ".2f"),
    ("p99 ms", "p99", ">8", ".2f"),
    ("max ms", "max", ">8", ".1f"),
    ("state", "state", ">7", ""),
]


def bench_flood(seconds: float) -> None:
    runs = [
        flood("none", 0, seconds),
        flood("junk", 50_000, seconds),
        flood("forged", 50_000, seconds),
    ]
    print(f"Flood on 127.0.0.1, {seconds:g} s per run, sensor at 50 Hz, budget {BUDGET_MS:.0f} ms")
    print(" ".join(f"{title:{align}}" for title, _, align, _ in COLUMNS) + "  alarm transitions")
    for r in runs:
        cells = [f"{r[key]:{align}{fmt}}" for _, key, align, fmt in COLUMNS]
        print(" ".join(cells) + f"  {r['alarms']}")
    print("seen < sent: the kernel dropped datagrams at a full socket buffer;")
    print("shed: well-formed datagrams dropped without a signature check under overload")
    print()


def main() -> None:
    quick = "--quick" in sys.argv
    bench_hashing(200_000 if quick else 1_000_000)
    bench_messages(1_000 if quick else 5_000)
    bench_flood(1.0 if quick else 3.0)


if __name__ == "__main__":
    os.environ.setdefault("PYTHONHASHSEED", "0")
    main()
