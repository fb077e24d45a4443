"""Helpers for link tests: deterministic keys, bearings and messages at a fixed time."""

from __future__ import annotations

import numpy as np
from cryptography.hazmat.primitives.asymmetric import ec

from rfsas_hw.link import SafetyMessage
from rfsas_hw.link.transport import Transport
from rfsas_hw.privacy.epochs import EpochSchedule
from rfsas_hw.records import BearingBatch, Pose

NOW_NS = 1_763_800_030_000_000_000
"""A receive time in the middle of a 60 s epoch."""
SCHEDULE = EpochSchedule(60.0, 5.0)
POSE = Pose(10.0, -20.0, 45.0)


def key(scalar: int) -> ec.EllipticCurvePrivateKey:
    """A deterministic P-256 key (tests only)."""
    return ec.derive_private_key(scalar, ec.SECP256R1())


def bearings(sender_id: str, n: int, t_ns: int, seed: int = 0) -> BearingBatch:
    rng = np.random.default_rng(seed)
    return BearingBatch(
        sensor_id=sender_id,
        t_ns=np.full(n, t_ns, np.int64) - rng.integers(0, 5_000_000, n),
        azimuth_deg=rng.uniform(0, 360, n),
        sigma_deg=rng.uniform(0.5, 10, n),
        snr_db=rng.uniform(0, 40, n),
        channel=rng.choice([1, 6, 11, 37, 149], n).astype(np.int16),
        emitter=rng.integers(0, 2**63, n, dtype=np.uint64) * np.uint64(2) + np.uint64(1),
    )


def message(
    sender_id: str = "rsu-1",
    n: int = 3,
    t_gen_ns: int = NOW_NS - 20_000_000,
    seq: int = 7,
    epoch: int | None = None,
    pose: Pose = POSE,
    seed: int = 0,
) -> SafetyMessage:
    batch = bearings(sender_id, n, t_gen_ns, seed)
    return SafetyMessage(
        sender_id=sender_id,
        pose=pose,
        t_gen_us=t_gen_ns // 1000,
        seq=seq,
        epoch=SCHEDULE.epoch_of(int(batch.t_ns.min())) if epoch is None else epoch,
        bearings=batch,
    )


class Queued(Transport):
    """Datagrams already there, for :meth:`Receiver.receive` (no socket)."""

    def __init__(self, items: list[bytes]) -> None:
        self.items = list(items)

    def send(self, datagram: bytes) -> None:
        raise NotImplementedError

    def recv(self, timeout: float | None = None) -> bytes | None:
        return self.items.pop(0) if self.items else None

    def close(self) -> None:
        self.items.clear()


class Kept(Transport):
    """Keeps what is sent, for a publisher's output (no socket)."""

    def __init__(self) -> None:
        self.sent: list[bytes] = []

    def send(self, datagram: bytes) -> None:
        self.sent.append(datagram)

    def recv(self, timeout: float | None = None) -> bytes | None:
        return None

    def close(self) -> None:
        pass
