"""Backend speed: exact P(collision) next to Monte Carlo, fixes per second next to scipy.

    python bench/bench_backend.py

Probability of collision, on 200 random vehicle/threat pairs (boxes, headings,
covariances like the tests use):

- rfsas-hw exact (Owen's T over the Minkowski octagon), one call at a time —
  goal ≤ 100 µs per call — and vectorised over all pairs;
- Lambert's Monte Carlo (separating axes, vectorised numpy) with as many
  samples as it needs for the same accuracy as the exact answer's tolerance
  in the tests (standard error 1e-3 at the case's p, so n = p(1−p)·1e6), and
  with the 1e6 samples the tests use as reference.

Triangulation, three stations, 1° bearings, one emitter per fix:

- rfsas-hw ``triangulate_batch`` over 20,000 fixes at once;
- rfsas-hw ``triangulate`` one fix per call;
- ``scipy.optimize.least_squares`` on the same azimuth residuals, one fix per call
  (what one would write without this package), on a subset.

Ratios are from this one run; the machine may be shared and noisy.
"""

from __future__ import annotations

import time

import numpy as np
from benchtime import timed
from scipy.optimize import least_squares

from rfsas_hw.angles import compass_to_math_rad, math_rad_to_compass, wrap_rad_pi
from rfsas_hw.backend import (
    collision_probability,
    collision_probability_batch,
    collision_probability_mc,
    triangulate,
    triangulate_batch,
)

GOAL_EXACT_US = 100.0


def random_cases(n: int, seed: int = 1) -> list[dict[str, object]]:
    rng = np.random.default_rng(seed)
    cases = []
    for _ in range(n):
        a, b = rng.normal(size=(2, 2)), rng.normal(size=(2, 2))
        cases.append(
            {
                "vehicle_xy": rng.uniform(-2, 2, 2),
                "vehicle_heading_deg": float(rng.uniform(0, 360)),
                "vehicle_cov": a @ a.T * rng.uniform(0.05, 4.0),
                "vehicle_size": rng.uniform(0.3, 5.0, 2),
                "threat_xy": rng.uniform(-4, 4, 2),
                "threat_heading_deg": float(rng.uniform(0, 360)),
                "threat_cov": b @ b.T * rng.uniform(0.05, 4.0),
                "threat_size": rng.uniform(0.3, 5.0, 2),
            }
        )
    return cases


def bench_collision() -> list[tuple[str, str, str]]:
    cases = random_cases(200)
    exact = [collision_probability(**c) for c in cases]  # type: ignore[arg-type]
    t_single = timed(lambda: [collision_probability(**c) for c in cases], 3) / len(cases)  # type: ignore[arg-type]
    stacked = {k: np.array([c[k] for c in cases]) for k in cases[0]}
    t_batch = timed(lambda: collision_probability_batch(**stacked), 3) / len(cases)
    # Monte Carlo for the same accuracy on a handful of the cases (it is slow)
    mc_cases = cases[:10]
    t_mc_same = 0.0
    t_mc_ref = 0.0
    worst = 0.0
    for i, c in enumerate(mc_cases):
        p = exact[i]
        n_same = max(int(p * (1 - p) * 1e6), 1000)
        t0 = time.perf_counter()
        collision_probability_mc(**c, n=n_same, seed=3)  # type: ignore[arg-type]
        t_mc_same += time.perf_counter() - t0
        t0 = time.perf_counter()
        ref = collision_probability_mc(**c, n=1_000_000, seed=4)  # type: ignore[arg-type]
        t_mc_ref += time.perf_counter() - t0
        worst = max(worst, abs(ref.p - p))
    t_mc_same /= len(mc_cases)
    t_mc_ref /= len(mc_cases)
    goal = "meets" if t_single * 1e6 <= GOAL_EXACT_US else "MISSES"
    return [
        ("exact, one call", f"{t_single * 1e6:9.1f} µs", f"goal ≤ {GOAL_EXACT_US:.0f} µs: {goal}"),
        ("exact, batch of 200", f"{t_batch * 1e6:9.1f} µs", f"{t_single / t_batch:.1f}× faster"),
        (
            "Monte Carlo, SE 1e-3",
            f"{t_mc_same * 1e6:9.0f} µs",
            f"{t_mc_same / t_single:.0f}× the exact call",
        ),
        (
            "Monte Carlo, 1e6 samples",
            f"{t_mc_ref * 1e6:9.0f} µs",
            f"{t_mc_ref / t_single:.0f}× the exact call; max |Δ| {worst:.1e}",
        ),
    ]


def bench_triangulation() -> list[tuple[str, str, str]]:
    rng = np.random.default_rng(2)
    stations = np.array([[-50.0, -50.0], [50.0, -50.0], [0.0, 60.0]])
    B = 20_000
    targets = rng.uniform(-20, 20, (B, 2))
    d = targets[:, None, :] - stations[None]
    az = math_rad_to_compass(np.arctan2(d[..., 1], d[..., 0])) + rng.normal(0, 1.0, (B, 3))
    sig = np.ones(3)
    S = np.broadcast_to(stations, (B, 3, 2))
    t_batch = timed(lambda: triangulate_batch(S, az, sig), 2)
    m = 1000
    t_single = timed(lambda: [triangulate(stations, az[i], sig) for i in range(m)], 1)
    phi = compass_to_math_rad(az[:200])
    w = 1.0 / np.deg2rad(1.0)

    def resid(p: np.ndarray, k: int) -> np.ndarray:
        pred = np.arctan2(p[1] - stations[:, 1], p[0] - stations[:, 0])
        return np.asarray(wrap_rad_pi(phi[k] - pred) * w)

    t_scipy = timed(lambda: [least_squares(resid, np.zeros(2), args=(k,)) for k in range(200)], 1)
    batch_rate = B / t_batch
    single_rate = m / t_single
    scipy_rate = 200 / t_scipy
    return [
        ("triangulate_batch", f"{batch_rate:9.0f} fixes/s", f"{batch_rate / scipy_rate:.0f}×"),
        ("triangulate, 1 call", f"{single_rate:9.0f} fixes/s", f"{single_rate / scipy_rate:.1f}×"),
        ("scipy least_squares", f"{scipy_rate:9.0f} fixes/s", "1× (reference)"),
    ]


def main() -> None:
    rows = [("P(collision)", "", ""), *bench_collision()]
    rows += [("triangulation (3 stations), fixes/s vs scipy", "", ""), *bench_triangulation()]
    width = max(len(r[0]) for r in rows)
    for name, value, note in rows:
        if not value:
            print(f"\n{name}")
            continue
        print(f"  {name:<{width}}  {value:>18}   {note}")


if __name__ == "__main__":
    main()
