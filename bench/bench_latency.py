"""End-to-end latency: a frame arrives → an advisory is out, over real loopback UDP.

    python bench/bench_latency.py [--frames 2000]

Each iteration is one frame heard by two sensors (a roadside unit and a car)
at the moment it arrives, and everything a deployment does with it:

1. DF and hashing: :class:`~rfsas_hw.pipeline.SensorPipeline` on the frame
   (calibration table lookup, keyed MAC hash), in each sensor;
2. signing and sending: :class:`~rfsas_hw.link.Publisher` (ECDSA P-256,
   one datagram per sensor) over UDP to 127.0.0.1;
3. verification: the backend's :class:`~rfsas_hw.link.Receiver` (signature,
   replay, age, epoch);
4. the backend: association, triangulation, tracking, P(collision) and the
   advisory (:meth:`~rfsas_hw.backend.service.BackendService.step`).

Side by side with what one might write instead: the same bearings as
unsigned JSON over the same UDP socket pair, triangulated with the same
backend (no signature, no verification). Goal: p99 ≤ 5 ms for the full path.
The latency budget of a safety message (method.md §7) is 100 ms.
"""

from __future__ import annotations

import argparse
import json
import socket
import time

import numpy as np
from cryptography.hazmat.primitives.asymmetric import ec

from rfsas_hw.backend.service import BackendService
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.link import Publisher, Receiver, Signer, TrustedKeys, open_transport
from rfsas_hw.pipeline import SensorPipeline
from rfsas_hw.privacy.hashing import FixedNonce, MacHasher
from rfsas_hw.records import BearingBatch, ObservationBatch, Pose
from rfsas_hw.rf.antenna import GaussianBeamPair
from rfsas_hw.twin.scenario import scenario_from_mapping
from rfsas_hw.twin.turntable import turntable_calibration

GOAL_P99_MS = 5.0
BUDGET_MS = 100.0
MAC = 0x3C22FB4E9107
TARGET = np.array([3.0, -8.5])
SENSORS = {
    "rsu": Pose(-9.0, 9.0, 140.0),
    "car": Pose(1.75, -40.0, 10.0),
}


def calibrations() -> dict[str, object]:
    data = {
        "version": 1,
        "name": "bench",
        "seed": 1,
        "duration_s": 1.0,
        "emitters": [
            {
                "id": "e",
                "mac": "02:00:00:00:00:01",
                "tech": "wifi",
                "position": [0, 0],
                "traffic": [{"model": "beacon"}],
            }
        ],
        "sensors": [
            {
                "id": sid,
                "kind": "roadside",
                "pose": {"x_m": p.x_m, "y_m": p.y_m, "heading_deg": p.heading_deg},
                "antenna": {"squint_deg": 15, "beamwidth_deg": 30},
            }
            for sid, p in SENSORS.items()
        ],
    }
    sc = scenario_from_mapping(data, "<bench>")
    return {sid: turntable_calibration(sc, sid) for sid in SENSORS}


def frame_for(sid: str, t_ns: int, rng: np.random.Generator) -> ObservationBatch:
    """One observation of the emitter at TARGET, as the sensor's card would report it."""
    pose = SENSORS[sid]
    d = TARGET - np.array([pose.x_m, pose.y_m])
    az = np.degrees(np.arctan2(d[0], d[1]))
    rel = (az - pose.heading_deg + 180) % 360 - 180
    g = GaussianBeamPair(15, 30).gains_db(rel)
    rssi = np.round(-55 + g + rng.normal(0, 0.7, 2))
    return ObservationBatch(
        t_ns=np.array([t_ns]),
        mac=np.array([MAC], np.uint64),
        freq_mhz=np.array([2437]),
        channel=np.array([6]),
        rssi_dbm=rssi[None, :].astype(np.float32),
    )


def vehicle(now: int) -> VehicleState:
    return VehicleState(1.75, -40.0, 0.0, 15.0, t_ns=now)


def run_signed(n: int, cals: dict[str, object]) -> dict[str, np.ndarray]:
    trust = TrustedKeys()
    signers = {}
    for sid in SENSORS:
        signers[sid] = Signer(sid, ec.generate_private_key(ec.SECP256R1()))
        trust.enroll(sid, signers[sid].public_key)
    receiver = Receiver.listen("udp://127.0.0.1:0", trust)
    host, port = receiver.transport.address  # type: ignore[union-attr]
    hasher = MacHasher(FixedNonce(b"bench-nonce-0123456789"))
    pipes = {
        sid: SensorPipeline(cals[sid], hasher, sid, SENSORS[sid])  # type: ignore[arg-type]
        for sid in SENSORS
    }
    pubs = {
        sid: Publisher(signers[sid], open_transport(f"udp://{host}:{port}", "send"), SENSORS[sid])
        for sid in SENSORS
    }
    backend = BackendService()
    rng = np.random.default_rng(0)
    stages = {k: np.empty(n) for k in ("df", "sign_send", "verify", "backend", "total")}
    for i in range(n + 50):
        now = time.time_ns()
        frames = {sid: frame_for(sid, now, rng) for sid in SENSORS}
        t0 = time.perf_counter()
        bearings: list[BearingBatch] = []
        for sid in SENSORS:
            bearings.append(pipes[sid].process(frames[sid]))
        t1 = time.perf_counter()
        for sid, b in zip(SENSORS, bearings, strict=True):
            pubs[sid].on_bearings(b)
        t2 = time.perf_counter()
        got: list[object] = []
        while len(got) < len(SENSORS):
            got.extend(receiver.receive(timeout=1.0))
        t3 = time.perf_counter()
        for msg in got:
            backend.on_verified(msg)  # type: ignore[arg-type]
        backend.set_vehicle(vehicle(time.time_ns()))
        assessments = backend.step()
        t4 = time.perf_counter()
        assert assessments and assessments[0].advisory in ("brake", "caution", "clear")
        if i >= 50:  # warm-up
            k = i - 50
            stages["df"][k] = t1 - t0
            stages["sign_send"][k] = t2 - t1
            stages["verify"][k] = t3 - t2
            stages["backend"][k] = t4 - t3
            stages["total"][k] = t4 - t0
    for p in pubs.values():
        p.close()
    receiver.close()
    assert receiver.stats.verified == (n + 50) * len(SENSORS), receiver.stats.as_dict()
    return stages


def run_unsigned(n: int, cals: dict[str, object]) -> np.ndarray:
    """The same bearings as JSON over UDP, no signature, no verification."""
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    addr = rx.getsockname()
    hasher = MacHasher(FixedNonce(b"bench-nonce-0123456789"))
    pipes = {
        sid: SensorPipeline(cals[sid], hasher, sid, SENSORS[sid])  # type: ignore[arg-type]
        for sid in SENSORS
    }
    backend = BackendService()
    rng = np.random.default_rng(0)
    out = np.empty(n)
    for i in range(n + 50):
        now = time.time_ns()
        frames = {sid: frame_for(sid, now, rng) for sid in SENSORS}
        t0 = time.perf_counter()
        for sid in SENSORS:
            b = pipes[sid].process(frames[sid])
            p = SENSORS[sid]
            doc = {
                "sensor": sid,
                "pose": [p.x_m, p.y_m, p.heading_deg],
                "bearings": [
                    [
                        int(b.t_ns[j]),
                        int(b.emitter[j]),
                        float(b.azimuth_deg[j]),
                        float(b.sigma_deg[j]),
                        float(b.snr_db[j]),
                        int(b.channel[j]),
                    ]
                    for j in range(len(b))
                ],
            }
            tx.sendto(json.dumps(doc).encode(), addr)
        for _ in SENSORS:
            doc = json.loads(rx.recv(65536))
            rows = np.array(doc["bearings"], dtype=object)
            batch = BearingBatch(
                sensor_id=doc["sensor"],
                t_ns=rows[:, 0].astype(np.int64),
                azimuth_deg=rows[:, 2].astype(float),
                sigma_deg=rows[:, 3].astype(float),
                snr_db=rows[:, 4].astype(float),
                channel=rows[:, 5].astype(np.int16),
                emitter=np.array([int(v) for v in rows[:, 1]], np.uint64),
            )
            backend.on_bearings(batch, Pose(*doc["pose"]))
        backend.set_vehicle(vehicle(time.time_ns()))
        backend.step()
        if i >= 50:
            out[i - 50] = time.perf_counter() - t0
    rx.close()
    tx.close()
    return out


def ms(a: np.ndarray, q: float) -> float:
    return float(np.percentile(a, q) * 1e3)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=2000)
    args = ap.parse_args()
    cals = calibrations()
    stages = run_signed(args.frames, cals)
    plain = run_unsigned(args.frames, cals)
    print(
        f"End-to-end latency, frame arrival → advisory, {args.frames} frames × 2 sensors, "
        "loopback UDP"
    )
    print()
    print(f"{'path':<46} {'p50 ms':>8} {'p90 ms':>8} {'p99 ms':>8} {'max ms':>8}")
    rows = [
        ("  DF + hashing (2 sensors)", stages["df"]),
        ("  sign + send (ECDSA P-256, 2 datagrams)", stages["sign_send"]),
        ("  receive + verify (2 messages)", stages["verify"]),
        ("  backend: associate, triangulate, risk", stages["backend"]),
        ("rfsas-hw, signed and verified (total)", stages["total"]),
        ("unsigned JSON over UDP, same backend", plain),
    ]
    for name, a in rows:
        print(f"{name:<46} {ms(a, 50):8.3f} {ms(a, 90):8.3f} {ms(a, 99):8.3f} {ms(a, 100):8.3f}")
    p99 = ms(stages["total"], 99)
    print()
    print(
        f"signed / unsigned at p50: {ms(stages['total'], 50) / ms(plain, 50):.2f}×, "
        f"at p99: {p99 / ms(plain, 99):.2f}×"
    )
    print(
        f"goal p99 ≤ {GOAL_P99_MS:g} ms: {'met' if p99 <= GOAL_P99_MS else 'NOT met'} "
        f"({p99:.2f} ms); {p99 / BUDGET_MS:.1%} of the 100 ms message budget"
    )


if __name__ == "__main__":
    main()
