"""What RF-SAS costs a simulator per step, beside the simulator's own step.

Runs the bundled SUMO crossing through libsumo with the bridge attached
(streaming twin → sources → sensor pipeline → backend) and times every
step, SUMO's ``simulationStep`` and the bridge's ``step`` separately:

- the bundled scene: one pedestrian with a phone, three roadside units and
  the ego's unit;
- the same junction filled with N walkers (phones) and vehicles (hotspots,
  every one carrying a device), four units, for N = 10, 30, 100: how the
  cost grows with the number of entities.

The goal for 10 Hz real time is ≤ 2 ms per step for the small scene and
≤ 20 ms for 100 entities on one core. Times are CPU time of this process
(``time.process_time``), medians over the steps, so that other load on the
machine counts as little as possible; wall time is printed too.

Run: ``python bench/bench_bridge.py [STEPS]`` (needs the ``[sumo]`` extra).

Measured last with ``python bench/bench_bridge.py 60``, seven rounds alternating
the code before and after the DF memo's neighbours and the twin's one-emitter
shortcuts (docs/simulators.md §6), on the shared 2-core machine (load average
3.7-5.1): bundled crossing 1.59-2.56 ms per step after (median 1.87; SUMO's
step 0.007-0.008 ms in every run) against 1.88-3.68 ms before (median 3.32;
SUMO 0.008-0.021 ms). The part of the step outside the backend, in units of the
backend's own time, went from 3.18-3.70 to 2.43-2.98 (medians 3.43 and 2.77).
Before, on a quiet machine, the bundled step took 2.07-2.13 ms in the host's
fast state. +100 entities 11.5-17.3 ms, within its 20 ms. Then, everything
merged, fourteen runs on a quiet machine (load 0.7-0.9): 1.79, 1.84 and 1.94 ms
in the host's fast state (backend 0.43-0.49 ms), 2.07-3.40 ms when it ran
slower: the goal holds on a fast host only.

The ``backend ms`` column is the part of the bridge's CPU time spent in the
backend's bearing intake and step (association, triangulation, tracking,
assessment), median per step: on a loaded machine (load average 3–4) 0.43–0.66
ms of 2.0–2.8 ms for the bundled crossing, 4.0–4.4 ms of 11.4–13.3 ms at +100
entities.
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from rfsas_hw.bridges.bridge import Bridge
from rfsas_hw.bridges.config import KindDevices
from rfsas_hw.bridges.sumo import SumoAdapter, load_sumo, read_buildings
from rfsas_hw.bridges.sumo_run import load_run_file

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "sumo"
ROUTES = (
    ("bottom0A0", "A0top0"),
    ("top0A0", "A0bottom0"),
    ("left0A0", "A0right0"),
    ("right0A0", "A0left0"),
    ("bottom0A0", "A0right0"),
    ("left0A0", "A0top0"),
)
WALKS = (
    ("left0A0", "bottom0A0"),
    ("bottom0A0", "A0left0"),
    ("right0A0", "A0top0"),
    ("top0A0", "A0right0"),
)


def _populate(sumo: object, n: int) -> None:
    """Add ``n`` entities: two walkers for every vehicle, spread over the first seconds."""
    s = sumo  # libsumo module
    for k, (a, b) in enumerate(ROUTES):
        s.route.add(f"r{k}", [a, b])  # type: ignore[attr-defined]
    n_veh = n // 3
    for k in range(n_veh):
        s.vehicle.add(  # type: ignore[attr-defined]
            f"v{k}", f"r{k % len(ROUTES)}", typeID="car", depart=str(0.1 * k), departPos="random"
        )
    for k in range(n - n_veh):
        a, b = WALKS[k % len(WALKS)]
        s.person.add(f"w{k}", a, pos=10.0 + (7.0 * k) % 70.0, depart=0.05 * k, typeID="walker")  # type: ignore[attr-defined]
        s.person.appendWalkingStage(f"w{k}", [a, b], arrivalPos=50.0)  # type: ignore[attr-defined]


def measure(n_extra: int, steps: int, *, all_devices: bool) -> dict[str, float]:
    """Median CPU and wall ms per step of SUMO and of the bridge."""
    cfg, run = load_run_file(EXAMPLE / "units.yaml")
    if all_devices:
        cfg = replace(
            cfg,
            devices={
                "pedestrian": KindDevices("phone-active", 1.0),
                "cyclist": KindDevices("phone-active", 1.0),
                "vehicle": KindDevices("hotspot", 1.0),
            },
        )
    sumo = load_sumo("libsumo")
    sumo.start(["sumo", "-c", str(EXAMPLE / "crossing.sumocfg"), "--end", "1000"])
    try:
        _populate(sumo, n_extra)
        adapter = SumoAdapter(sumo, run.ego, origin=cfg.origin_m)
        bridge = Bridge(cfg, buildings=read_buildings(sumo, cfg.origin_m))
        in_backend = [0.0]  # CPU s inside the backend (intake + step) during this step
        backend = bridge.backend
        take, judge = backend.on_bearings, backend.step

        def timed_take(*args: Any) -> None:
            c = time.process_time()
            take(*args)
            in_backend[0] += time.process_time() - c

        def timed_step(*args: Any, **kw: Any) -> Any:
            c = time.process_time()
            out = judge(*args, **kw)
            in_backend[0] += time.process_time() - c
            return out

        backend.on_bearings = timed_take  # type: ignore[method-assign]
        backend.step = timed_step  # type: ignore[method-assign]
        be_cpu: list[float] = []
        sumo_cpu: list[float] = []
        sumo_wall: list[float] = []
        br_cpu: list[float] = []
        br_wall: list[float] = []
        counts: list[int] = []
        while len(br_cpu) < steps:
            c0, w0 = time.process_time(), time.perf_counter()
            sumo.simulationStep()
            sumo_cpu.append(time.process_time() - c0)
            sumo_wall.append(time.perf_counter() - w0)
            ego, others = adapter.read()
            if ego is None:
                if adapter.ego_seen:
                    break
                continue
            c0, w0 = time.process_time(), time.perf_counter()
            in_backend[0] = 0.0
            bridge.step(float(sumo.simulation.getTime()), ego, others)
            br_cpu.append(time.process_time() - c0)
            be_cpu.append(in_backend[0])
            br_wall.append(time.perf_counter() - w0)
            counts.append(len(others))
        bridge.close()
    finally:
        sumo.close()
    ms = 1e3
    return {
        "entities": float(np.median(counts)) + 1,
        "units": float(len(bridge.unit_ids)),
        "steps": float(len(br_cpu)),
        "devices": float(bridge.stats.devices),
        "sumo_cpu_ms": float(np.median(sumo_cpu)) * ms,
        "sumo_wall_ms": float(np.median(sumo_wall)) * ms,
        "bridge_cpu_ms": float(np.median(br_cpu)) * ms,
        "bridge_wall_ms": float(np.median(br_wall)) * ms,
        "bridge_p90_cpu_ms": float(np.percentile(br_cpu, 90)) * ms,
        "backend_cpu_ms": float(np.median(be_cpu)) * ms,
    }


def main() -> None:
    steps = int(sys.argv[1]) if len(sys.argv) > 1 else 60
    # warm-up: imports, the turntable calibration fit (once per process)
    measure(0, 5, all_devices=False)
    rows = [("bundled crossing", measure(0, steps, all_devices=False))]
    for n in (10, 30, 100):
        rows.append((f"+{n} entities", measure(n, steps, all_devices=True)))
    head = (
        f"{'scene':18s} {'entities':>8s} {'units':>5s} {'devices':>7s} {'SUMO ms':>8s} "
        f"{'bridge ms':>9s} {'p90 ms':>7s} {'backend ms':>10s} {'wall ms':>8s} "
        f"{'bridge/SUMO':>11s} {'10 Hz used':>10s}"
    )
    print(head)
    print("-" * len(head))
    for name, r in rows:
        ratio = r["bridge_cpu_ms"] / max(r["sumo_cpu_ms"], 1e-6)
        print(
            f"{name:18s} {r['entities']:8.0f} {r['units']:5.0f} {r['devices']:7.0f} "
            f"{r['sumo_cpu_ms']:8.3f} {r['bridge_cpu_ms']:9.2f} {r['bridge_p90_cpu_ms']:7.2f} "
            f"{r['backend_cpu_ms']:10.2f} {r['bridge_wall_ms']:8.2f} {ratio:11.0f} "
            f"{r['bridge_cpu_ms'] / 100:10.1%}"
        )
    print(
        "times: median CPU ms per step of this process (backend: of that, in the backend's "
        "intake and step; wall: bridge median wall time)"
    )
    (_, small), (_, big) = rows[0], rows[-1]
    extra = max(big["entities"] - small["entities"], 1.0)
    print(
        f"growth from {small['entities']:.0f} to {big['entities']:.0f} entities: bridge "
        f"+{(big['bridge_cpu_ms'] - small['bridge_cpu_ms']) / extra:.3f} ms, SUMO "
        f"+{(big['sumo_cpu_ms'] - small['sumo_cpu_ms']) / extra:.4f} ms per extra entity"
    )


if __name__ == "__main__":
    main()
