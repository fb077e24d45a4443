"""How long the whole Euro NCAP VRU matrix takes: every scenario and true negative, the
default configurations of ``rfsas ncap``, three seeds.

Builds the same runs as ``rfsas ncap --seeds 3`` (every cell × the controllers
los, rfsas, rfsas+los and los+cue × the deployments car and car+rsu × the
devices phone-active and phone-idle × seeds 0–2) and runs them on the
project's runner (:func:`rfsas_hw.ncap.sweep.run_sweep`: a local Dask cluster
of WORKERS processes). Prints the number of runs, the wall time, runs per
second, the CPU time per run (each run's own thread, SUMO included: the
cost on an idle machine) and the load average before and after, since the
machine may be shared. The goal: the whole matrix in ≤ 20 min on a 2-core
machine.

On a shared machine the whole matrix may take far longer than the goal:
``--budget-min M`` stops after M minutes (the runs still queued are
cancelled) and reports the runs done and their rate, with the time the whole
matrix would take at that rate marked as an extrapolation; the runs are then
taken in a shuffled (seeded) order so that the ones done are a fair sample of
the matrix.

Run: ``python bench/bench_ncap.py [--workers 2] [--seeds 3] [--scenarios all]
[--budget-min M]`` (needs the ``[ncap]`` extra). docs/ncap.md ("Run time") has
the measured numbers.
"""

from __future__ import annotations

import argparse
import math
import os
import random
import statistics
import time
from collections import defaultdict

from rfsas_hw.ncap.runner import RunResult, run_one
from rfsas_hw.ncap.scenarios import SCENARIOS, TRUE_NEGATIVES, cells
from rfsas_hw.ncap.sweep import configs, specs_for
from rfsas_hw.parallel import completed

CONTROLLERS = ("los", "rfsas", "rfsas+los", "los+cue")
DEPLOYMENTS = ("car", "car+rsu")
DEVICES = ("phone-active", "phone-idle")
GOAL_S = 20 * 60


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workers", type=int, default=2, help="local Dask workers (0: here)")
    ap.add_argument("--seeds", type=int, default=3, help="seeds per cell")
    ap.add_argument("--scenarios", default="all", help="comma list, or 'all'")
    ap.add_argument("--budget-min", type=float, default=None, help="stop after this long")
    args = ap.parse_args()
    names = [*SCENARIOS, *TRUE_NEGATIVES] if args.scenarios == "all" else args.scenarios.split(",")
    chosen = cells(names)
    conf = configs(CONTROLLERS, DEPLOYMENTS, DEVICES)
    specs = specs_for(chosen, conf, list(range(args.seeds)))
    load0 = os.getloadavg()
    print(
        f"{len(chosen)} cells × {len(conf)} configurations × {args.seeds} seeds = "
        f"{len(specs)} runs on {args.workers} workers; load average before "
        f"{load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}",
        flush=True,
    )
    if args.budget_min is not None:
        random.Random(0).shuffle(specs)
    budget = math.inf if args.budget_min is None else args.budget_min * 60
    results: list[RunResult] = []
    w0 = time.perf_counter()
    pairs = completed(run_one, specs, workers=args.workers, name="bench-ncap")
    try:
        for _, r in pairs:
            results.append(r)
            if len(results) % 250 == 0:
                print(f"  {len(results)}/{len(specs)} after {time.perf_counter() - w0:.0f} s",
                      flush=True)  # fmt: skip
            if time.perf_counter() - w0 > budget:
                break
    finally:
        pairs.close()
    wall = time.perf_counter() - w0
    load1 = os.getloadavg()
    cpu = [r.cpu_s for r in results]
    by: dict[str, list[float]] = defaultdict(list)
    for r in results:
        by[r.controller].append(r.cpu_s)
    whole = len(results) == len(specs)
    print(f"runs             {len(results)} of {len(specs)}")
    print(f"workers          {args.workers}")
    print(f"wall             {wall:.1f} s ({wall / 60:.1f} min)")
    rate = len(results) / wall
    print(f"runs/s           {rate:.2f}")
    if whole:
        print(f"whole matrix     {wall / 60:.1f} min; goal {GOAL_S / 60:.0f} min: "
              f"{'met' if wall <= GOAL_S else 'NOT met'}")  # fmt: skip
    else:
        est = len(specs) / rate
        print(f"whole matrix     stopped by the budget; at this rate {est / 60:.1f} min "
              f"(extrapolated); goal {GOAL_S / 60:.0f} min: "
              f"{'met' if est <= GOAL_S else 'NOT met'}")  # fmt: skip
    print(f"CPU per run      {statistics.mean(cpu):.3f} s mean, "
          f"{statistics.median(cpu):.3f} s median, {sum(cpu):.0f} s in all")  # fmt: skip
    for ctl, v in sorted(by.items()):
        print(f"  {ctl:<10}     {statistics.mean(v):.3f} s mean over {len(v)} runs")
    ideal = statistics.mean(cpu) * len(specs) / max(args.workers, 1)
    print(f"idle machine     {ideal / 60:.1f} min for the whole matrix (CPU per run × runs / "
          "workers: the wall time if nothing else ran)")  # fmt: skip
    print(f"load average     before {load0[0]:.2f}, after {load1[0]:.2f} {load1[1]:.2f} "
          f"{load1[2]:.2f} (1, 5, 15 min)")  # fmt: skip


if __name__ == "__main__":
    main()
