"""A sensor pipeline without its epoch's nonce: frames wait (bounded), expire with a
counter, and flow again when the nonce arrives; the pipeline never raises for it."""

from __future__ import annotations

import numpy as np
import pytest

from rfsas_hw.df import fit_calibration
from rfsas_hw.pipeline import SensorPipeline
from rfsas_hw.privacy.hashing import (
    MacHasher,
    NonceExpiredError,
    NonceUnavailableError,
    hash_mac,
)
from rfsas_hw.records import ObservationBatch, Pose
from rfsas_hw.rf import GaussianBeamPair, ReceiverModel, rssi_pairs, turntable_sweep

ANT = GaussianBeamPair()
RX = ReceiverModel(measurement_floor_db=0.5)
EPOCH_S = 2.0
EPOCH_NS = int(EPOCH_S * 1e9)
T0 = 1_700_000_000 * 10**9 // EPOCH_NS * EPOCH_NS
MAC = 0x0200000000A1


class Authority:
    """A nonce provider the test controls: nonces are given, withheld or expired."""

    def __init__(self) -> None:
        self.given: dict[int, bytes] = {}
        self.expired: set[int] = set()

    def nonce_for(self, epoch: int) -> bytes:
        if epoch in self.expired:
            raise NonceExpiredError(f"epoch {epoch} is over")
        if epoch not in self.given:
            raise NonceUnavailableError(f"no nonce for epoch {epoch}")
        return self.given[epoch]


@pytest.fixture(scope="module")
def calibration():  # type: ignore[no-untyped-def]
    sweep = turntable_sweep(np.arange(-90.0, 90.5, 1.0), 30, -50.0, ANT, RX, seed=5)
    return fit_calibration(sweep, "linear")


def frames(epoch: int, n: int = 50) -> ObservationBatch:
    rssi = rssi_pairs(np.zeros(n), -50.0, ANT, RX, np.random.default_rng(epoch))
    return ObservationBatch(
        t_ns=T0 + epoch * EPOCH_NS + np.arange(n, dtype=np.int64) * 1_000_000,
        mac=np.full(n, MAC, np.uint64),
        freq_mhz=np.full(n, 2437),
        channel=np.full(n, 6),
        rssi_dbm=rssi,
    )


def epoch_no(k: int) -> int:
    return (T0 + k * EPOCH_NS) // EPOCH_NS


def make(calibration, hold_max: int = 10_000) -> tuple[SensorPipeline, Authority]:  # type: ignore[no-untyped-def]
    auth = Authority()
    hasher = MacHasher(auth, EPOCH_S)
    return SensorPipeline(calibration, hasher, "s1", Pose(0, 0, 0), hold_max=hold_max), auth


def test_frames_wait_for_a_late_nonce_and_are_released_in_order(calibration) -> None:  # type: ignore[no-untyped-def]
    pipe, auth = make(calibration)
    assert len(pipe.process(frames(0))) == 0
    assert pipe.alarm and pipe.stats.held == 50
    assert len(pipe.process(frames(0))) == 0  # same epoch: waits behind the first
    assert pipe.stats.held == 100
    auth.given[epoch_no(0)] = b"n0" * 16
    out = pipe.process(frames(1))  # epoch 1 is still missing: it waits now
    assert len(out) == 100
    assert set(out.emitter.tolist()) == {hash_mac(b"n0" * 16, MAC)}
    assert pipe.stats.held == 50 and pipe.alarm and pipe.stats.nonce_alarms == 2
    auth.given[epoch_no(1)] = b"n1" * 16
    released = pipe.release()  # no new frame needed
    assert len(released) == 50 and not pipe.alarm
    assert set(released.emitter.tolist()) == {hash_mac(b"n1" * 16, MAC)}
    assert pipe.stats.released == 150 and pipe.stats.nonce_alarms == 2
    assert pipe.stats.bearings == 150 and pipe.stats.held == 0


def test_frames_of_an_expired_epoch_are_dropped_and_counted(calibration) -> None:  # type: ignore[no-untyped-def]
    pipe, auth = make(calibration)
    pipe.process(frames(0))
    auth.expired.add(epoch_no(0))  # an outage longer than the epoch and its grace
    auth.given[epoch_no(1)] = b"n1" * 16
    out = pipe.process(frames(1))
    assert len(out) == 50  # the new epoch flows; the old one is gone
    assert pipe.stats.rejected["nonce_expired"] == 50
    assert pipe.stats.held == 0 and not pipe.alarm
    # an expired epoch's new frames are dropped straight away
    assert len(pipe.process(frames(0))) == 0
    assert pipe.stats.rejected["nonce_expired"] == 100 and pipe.alarm


def test_the_hold_queue_is_bounded_oldest_first(calibration) -> None:  # type: ignore[no-untyped-def]
    pipe, auth = make(calibration, hold_max=120)
    for k in range(4):
        pipe.process(frames(k))
    assert pipe.stats.held == 120 and pipe.stats.held_max == 120
    assert pipe.stats.rejected["hold_overflow"] == 80
    for k in range(4):
        auth.given[epoch_no(k)] = bytes([k]) * 32
    out = pipe.release()
    # the newest 120 frames survive: 20 of epoch 1, all of epochs 2 and 3
    assert len(out) == 120
    assert int(out.t_ns.min()) == T0 + EPOCH_NS + 30 * 1_000_000


def test_finish_counts_what_never_got_a_nonce(calibration) -> None:  # type: ignore[no-untyped-def]
    pipe, _ = make(calibration)
    pipe.process(frames(0))
    assert len(pipe.finish()) == 0
    assert pipe.stats.rejected["nonce_unavailable"] == 50 and pipe.stats.held == 0


def test_finish_waits_a_bounded_time_for_a_late_nonce(calibration) -> None:  # type: ignore[no-untyped-def]
    import threading
    import time

    pipe, auth = make(calibration)
    pipe.process(frames(0))
    timer = threading.Timer(0.3, lambda: auth.given.__setitem__(epoch_no(0), b"n0" * 16))
    timer.start()
    t0 = time.monotonic()
    out = pipe.finish(wait_s=5.0)
    timer.join()
    assert len(out) == 50 and time.monotonic() - t0 < 3.0
    assert not pipe.stats.rejected
    # without the nonce it gives up after the wait and counts the frames
    pipe.process(frames(3))
    t0 = time.monotonic()
    assert len(pipe.finish(wait_s=0.3)) == 0
    assert 0.25 < time.monotonic() - t0 < 3.0
    assert pipe.stats.rejected["nonce_unavailable"] == 50
