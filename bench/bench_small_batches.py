"""What the two shortcuts for a few frames save: the DF memo and per-frame MAC hashing.

    python bench/bench_small_batches.py

A live sensor, and every unit of the simulator bridge, hands the pipeline a
few frames at a time (one to eight per 0.1 s step in the bundled crossing).
Two stages then take a shortcut that reuses the reference code:

- DF: :class:`rfsas_hw.pipeline._DfMemo` keeps the results of
  :func:`rfsas_hw.df.estimate` per (RSSI 1, RSSI 2, channel) and answers a
  batch whose pairs it has seen (drivers report RSSI in half dB) without
  calling it; otherwise it calls it.
- Hashing: :meth:`MacHasher.hash_batch` up to ``SMALL_BATCH`` frames looks
  each MAC up in the epoch's cache (``hash_one``) instead of sorting the
  batch with ``np.unique``.

For each batch size this prints the CPU time per batch of the reference
(estimate; hashing with the shortcut off) and of the shortcut, on cached
inputs (the common case after the first seconds). Times are CPU seconds of
this process, best of five.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from rfsas_hw import pipeline
from rfsas_hw.df import fit_calibration
from rfsas_hw.df.estimate import estimate
from rfsas_hw.privacy import hashing
from rfsas_hw.privacy.hashing import FixedNonce, MacHasher
from rfsas_hw.records import ObservationBatch
from rfsas_hw.rf import GaussianBeamPair, ReceiverModel, turntable_sweep

T0_NS = 1_700_000_000 * 10**9


def per_call_us(fn: Callable[[], object], reps: int = 2000) -> float:
    """Best of five: CPU microseconds per call."""
    best = float("inf")
    for _ in range(5):
        t0 = time.process_time()
        for _ in range(reps):
            fn()
        best = min(best, (time.process_time() - t0) / reps)
    return best * 1e6


def main() -> None:
    sweep = turntable_sweep(
        np.arange(-90.0, 90.5, 1.0), 30, -50.0, GaussianBeamPair(), ReceiverModel(), seed=5
    )
    cal = fit_calibration(sweep, "linear")
    rng = np.random.default_rng(0)
    print(f"{'frames per batch':<18} {'DF estimate':>12} {'DF memo':>9} "
          f"{'hash np.unique':>15} {'hash per frame':>15}  (µs per batch)")  # fmt: skip
    for n in (1, 2, 4, 8):
        rssi = (np.round(rng.uniform(-70.0, -40.0, (n, 2)) * 2) / 2).astype(np.float32)
        batch = ObservationBatch(
            t_ns=T0_NS + np.arange(n, dtype=np.int64) * 1_000_000,
            mac=np.arange(n, dtype=np.uint64) + np.uint64(0x0200000000A1),
            freq_mhz=np.full(n, 2437),
            channel=np.full(n, 6, np.int16),
            rssi_dbm=rssi,
        )
        memo = pipeline._DfMemo(cal, None)
        memo.estimate(batch)  # the pairs are known from now on
        ref = per_call_us(
            lambda b=batch: estimate(cal, b.rssi_dbm[:, 0], b.rssi_dbm[:, 1], b.channel)
        )
        hit = per_call_us(lambda b=batch, m=memo: m.estimate(b))
        hasher = MacHasher(FixedNonce(bytes(32)))
        hasher.hash_batch(batch.mac, batch.t_ns)  # the MACs are cached from now on
        small = hashing.SMALL_BATCH
        hashing.SMALL_BATCH = 0
        sort = per_call_us(lambda b=batch, h=hasher: h.hash_batch(b.mac, b.t_ns))
        hashing.SMALL_BATCH = small
        loop = per_call_us(lambda b=batch, h=hasher: h.hash_batch(b.mac, b.t_ns))
        print(f"{n:<18} {ref:>12.1f} {hit:>9.1f} {sort:>15.1f} {loop:>15.1f}")


if __name__ == "__main__":
    main()
