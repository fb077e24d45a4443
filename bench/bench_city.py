"""The district's cost as the work grows: real-time factor and CPU share per component.

    python bench/bench_city.py [--duration 60] [--vrus 250,500,1000] [--net NET]
        [--deployment-nice N]

Needs the ``city`` extra and ``mosquitto``. For each VRU count, one ``rfsas city
run`` with RF-SAS on, on the Berlin-Adlershof net of the ``eclipse-sumo`` wheel
by default: cars = half the VRUs, 80 % pedestrians and 20 % cyclists, 90 % of
the VRUs with a phone (20 % of the phones in active use, the others idle),
departures over the first half of the run, two units at every traffic light,
two backend and two twin-worker processes, mosquitto with mutual TLS on
loopback, the deployment's clock at real time.

Printed per row: the real-time factor of the stepping loop (simulated seconds
per wall second; 1.0 is real time), the most VRUs with a phone at one time,
bearing messages per second and the share the backends verified (the rest
arrived too late: ``stale``, ``wrong_epoch``), advisories per second, messages
lost in the broker, frame → advisory latency p50/p99 (ms), and each
component's CPU seconds per wall second (1.00 = one core): SUMO, reading its
state, the scorer, the main process's share of the path (snapshots, pipes,
acting on advisories), the vehicles' receivers, the twin workers, the
backends and the broker. The machine has 2 cores; the sum of the shares is
the load the run puts on it.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from rfsas_hw.city.demand import DemandConfig
from rfsas_hw.city.live import LiveConfig
from rfsas_hw.city.run import CityRunConfig, run_city


def _row(vrus: int, duration_s: float, net: Path | None, seed: int, nice: int) -> dict[str, object]:
    demand = DemandConfig(
        vehicles=vrus // 2,
        pedestrians=round(vrus * 0.8),
        bicycles=vrus - round(vrus * 0.8),
        end_s=duration_s / 2,
        phone_penetration=0.9,
        device_mix={"phone-active": 0.2, "phone-idle": 0.8},
    )
    cfg = CityRunConfig(
        net=net, demand=demand, duration_s=duration_s, seed=seed, live=LiveConfig(nice=nice)
    )
    with tempfile.TemporaryDirectory(prefix="bench-city-") as tmp:
        res = run_city(cfg, Path(tmp), "on", png=False)
        seconds = [
            json.loads(ln)
            for ln in res.files["log"].read_text().splitlines()
            if '"record": "second"' in ln
        ]
    rt = res.runtime
    return {
        "vrus": vrus,
        "cars": demand.vehicles,
        "phones_at_once": max((s["vrus_with_phone"] for s in seconds), default=0),
        "realtime_factor": round(rt.realtime_factor, 3),
        "behind_s": round(rt.behind_s, 2),
        "bearing_messages_per_s": round(rt.counts.get("bearing_messages_sent", 0) / rt.wall_s, 1),
        "advisories_per_s": round(rt.counts.get("advisories_received", 0) / rt.wall_s, 1),
        "verified_share": round(
            rt.counts.get("bearing_messages_verified", 0)
            / max(rt.counts.get("bearing_messages_sent", 0), 1),
            3,
        ),
        "lost": rt.counts.get("bearing_messages_sent", 0)
        - rt.counts.get("bearing_messages_received", 0)
        + rt.counts.get("advisories_sent", 0)
        - rt.counts.get("advisories_received", 0),
        "latency_p50_ms": res.summary.latency_p50_ms,
        "latency_p99_ms": res.summary.latency_p99_ms,
        "latency_parts_ms": res.summary.latency_parts_ms,
        "cpu_share": {k: round(v, 3) for k, v in rt.cpu_share().items()},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0, help="simulated seconds per row")
    ap.add_argument("--vrus", default="250,500,1000", help="VRU counts, comma separated")
    ap.add_argument("--net", type=Path, default=None, help="SUMO net (default: Adlershof)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--deployment-nice",
        type=int,
        default=0,
        help="nice levels of the workers, backends and receivers below the simulator",
    )
    args = ap.parse_args()
    rows = [
        _row(int(v), args.duration, args.net, args.seed, args.deployment_nice)
        for v in args.vrus.split(",")
    ]
    keys = sorted({k for r in rows for k in r["cpu_share"]})  # type: ignore[attr-defined]
    head = ["VRUs", "cars", "phones", "RTF", "bear/s", "verified", "adv/s", "lost", "p50", "p99"]
    head += ["p99 to step / judging / delivery"]
    head += keys
    print(" | ".join(head))
    for r in rows:
        share = r["cpu_share"]
        cells = [
            r["vrus"],
            r["cars"],
            r["phones_at_once"],
            r["realtime_factor"],
            r["bearing_messages_per_s"],
            r["verified_share"],
            r["advisories_per_s"],
            r["lost"],
            r["latency_p50_ms"],
            r["latency_p99_ms"],
            " / ".join(str(part.get("p99")) for part in r["latency_parts_ms"].values()),  # type: ignore[attr-defined]
            *(share.get(k, "") for k in keys),  # type: ignore[attr-defined]
        ]
        print(" | ".join(str(c) for c in cells))
    print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
