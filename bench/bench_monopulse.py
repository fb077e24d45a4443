"""Bearings per second from RSSI pairs: rfsas-hw's estimator next to what a user would write.

    python bench/bench_monopulse.py [N]

Compares, on the same N random RSSI pairs (default 1,000,000) and the
bundled example calibration:
- rfsas-hw ``df.estimate``: vectorised ratio, uniform-ψ lookup table, σ and flags;
- ``numpy.interp`` inverse interpolation (the obvious vectorised version, no σ);
- the published brute-force search (argmin |ψ − ψ_D| over the grid), on a
  subset, chunked to bound memory;
- a per-frame Python loop with ``bisect`` (what a quick script does), on a subset.
Ratios are from this one run; the machine may be shared and noisy.
"""

from __future__ import annotations

import bisect
import sys
from pathlib import Path

import numpy as np
from benchtime import timed

from rfsas_hw.df import estimate, load_calibration, ratio

ROOT = Path(__file__).resolve().parent.parent
GOAL_PER_S = 10_000_000


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 1_000_000
    cal = load_calibration(ROOT / "calibration" / "example_cal.yaml")
    table = cal.tables[0]
    rng = np.random.default_rng(0)
    r1 = rng.integers(-80, -40, n).astype(np.float32)
    r2 = (r1 + rng.integers(-6, 7, n)).astype(np.float32)
    psi64 = ratio(r1.astype(np.float64), r2.astype(np.float64), table.k_d, cal.mode)

    rows: list[tuple[str, int, float]] = []
    channel = np.full(n, table.channel or 0, np.int16)
    t = timed(lambda: estimate(cal, r1, r2, channel))
    rows.append(("rfsas-hw df.estimate (angle, σ, flags)", n, t))
    t = timed(lambda: np.interp(psi64, table._inv_psi, table._inv_deg))
    rows.append(("numpy.interp on precomputed ψ (angle only)", n, t))
    m = min(n, 100_000)
    chunks = np.array_split(psi64[:m], max(1, m // 10_000))
    t = timed(lambda: [table.search_angle(c) for c in chunks], repeat=1)
    rows.append(("brute-force argmin |ψ − ψ_D| (published)", m, t))
    k = min(n, 100_000)
    xs, ys = table._inv_psi.tolist(), table._inv_deg.tolist()

    def loop() -> None:
        lr1, lr2 = r1[:k].tolist(), r2[:k].tolist()
        for a, b in zip(lr1, lr2, strict=True):
            p = 10 ** (a / 10)
            q = table.k_d * 10 ** (b / 10)
            psi = (p - q) / (p + q)
            i = min(max(bisect.bisect_left(xs, psi), 1), len(xs) - 1)
            x0, x1 = xs[i - 1], xs[i]
            _ = ys[i - 1] + (psi - x0) * (ys[i] - ys[i - 1]) / (x1 - x0)

    t = timed(loop, repeat=1)
    rows.append(("per-frame Python loop with bisect (angle only)", k, t))

    res = estimate(cal, r1, r2, channel)
    assert res.valid.mean() > 0.5, "benchmark inputs must mostly give valid bearings"
    ours = rows[0][1] / rows[0][2]
    print(f"Monopulse bearings, {n:,} RSSI pairs, table of {len(table.grid_deg)} angles")
    print(f"{'method':<48} {'frames':>10} {'time (ms)':>10} {'bearings/s':>14} {'rfsas-hw is':>12}")
    for name, count, secs in rows:
        rate = count / secs
        print(f"{name:<48} {count:>10,} {secs * 1e3:>10.1f} {rate:>14,.0f} {ours / rate:>11.1f}×")
    verdict = "meets" if ours >= GOAL_PER_S else "MISSES"
    print(f"goal ≥ {GOAL_PER_S:,} bearings/s: {verdict} ({ours:,.0f}/s)")


if __name__ == "__main__":
    main()
