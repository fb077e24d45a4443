"""Helpers for fleet tests: bearings stamped now, draining a receiver, nonces."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from rfsas_hw.link import Receiver, VerifiedMessage
from rfsas_hw.privacy.epochs import EpochSchedule
from rfsas_hw.records import BearingBatch

ORIGIN = "48.137,11.575"
SCHEDULE = EpochSchedule(60.0, 5.0)


def bearings_now(sender_id: str, n: int = 3, seed: int = 0) -> BearingBatch:
    rng = np.random.default_rng(seed)
    now = time.time_ns()
    return BearingBatch(
        sensor_id=sender_id,
        t_ns=np.full(n, now, np.int64) - rng.integers(0, 2_000_000, n),
        azimuth_deg=rng.uniform(0, 360, n),
        sigma_deg=rng.uniform(0.5, 5, n),
        snr_db=rng.uniform(5, 40, n),
        channel=np.full(n, 6, np.int16),
        emitter=rng.integers(1, 2**62, n, dtype=np.uint64),
    )


def drain(
    rx: Receiver, want: int, timeout_s: float = 5.0, until: Callable[[], bool] | None = None
) -> list[VerifiedMessage]:
    got: list[VerifiedMessage] = []
    deadline = time.monotonic() + timeout_s
    while len(got) < want and time.monotonic() < deadline:
        got += rx.receive(timeout=0.05)
        if until is not None and until():
            break
    return got


def well_inside_an_epoch(margin_s: float = 15.0) -> None:
    """Wait for the next epoch if this one ends within ``margin_s``."""
    left = SCHEDULE.epoch_s - (time.time() % SCHEDULE.epoch_s)
    if left < margin_s:
        time.sleep(left + 0.1)
