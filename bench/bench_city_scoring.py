"""Cost of one step of the district scorer, on the Berlin-Adlershof net.

    python bench/bench_city_scoring.py [--steps 300]

Cars stand on random points of the net's car lanes and VRUs (a fifth of
them cyclists) on its sidewalks, all heading along their lane at city speeds
(cars 0–14 m/s, pedestrians 0.8–1.5 m/s, cyclists 3–6 m/s), and move at
constant velocity for ``--steps`` steps of 0.1 s. Every step is scored by
:class:`~rfsas_hw.city.scoring.CityScorer` with the net's 503 crossings; every
tenth step adds 20 fixes and one BRAKE. The table gives the wall time of
``step`` (median, 90th percentile, mean) and its mean CPU time (which a
loaded machine inflates less) for 125/250, 250/500 and 500/1000 cars/VRUs; the
scorer must stay a small share of a 100 ms step. Needs the ``city`` extra.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from rfsas_hw.city.net import NetInfo, Road, district_net, read_net
from rfsas_hw.city.scoring import Actors, CityScorer

DT_S = 0.1
SIZES = ((125, 250), (250, 500), (500, 1000))


def on_lanes(roads: list[Road], n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` random (x, y, compass heading) points on ``roads``."""
    out = np.empty((n, 3))
    for k, r in enumerate(rng.integers(0, len(roads), n)):
        shape = np.asarray(roads[r].shape)
        i = int(rng.integers(0, len(shape) - 1))
        d = shape[i + 1] - shape[i]
        p = shape[i] + rng.random() * d
        out[k] = (p[0], p[1], np.degrees(np.arctan2(d[0], d[1])) % 360.0)
    return out


def run(
    info: NetInfo, cars: int, vrus: int, steps: int, seed: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """Per-step wall and CPU times of the scorer, milliseconds."""
    rng = np.random.default_rng(seed)
    car_lanes = [r for r in info.roads if r.cars and len(r.shape) > 1]
    walks = [r for r in info.roads if r.pedestrian_only and len(r.shape) > 1]
    v, u = on_lanes(car_lanes, cars, rng), on_lanes(walks, vrus, rng)
    bikes = vrus // 5
    v_speed = rng.uniform(0.0, 14.0, cars)
    u_speed = np.concatenate([rng.uniform(3.0, 6.0, bikes), rng.uniform(0.8, 1.5, vrus - bikes)])
    classes = ["bicycle"] * bikes + ["pedestrian"] * (vrus - bikes)
    u_len = np.where(np.arange(vrus) < bikes, 1.6, 0.215)
    u_wid = np.where(np.arange(vrus) < bikes, 0.65, 0.478)
    car_ids = [f"car{i}" for i in range(cars)]
    vru_ids = [f"vru{i}" for i in range(vrus)]
    route = np.zeros(cars)
    scorer = CityScorer(info.crossings)
    times, cpu = np.empty(steps), np.empty(steps)
    for k in range(steps):
        t = k * DT_S
        veh = Actors.of(
            car_ids, ["vehicle"] * cars, v[:, 0], v[:, 1], v_speed, v[:, 2], 4.5, 1.8, route
        )
        ppl = Actors.of(vru_ids, classes, u[:, 0], u[:, 1], u_speed, u[:, 2], u_len, u_wid)
        t0, c0 = time.perf_counter(), time.process_time()
        scorer.step(t, veh, ppl)
        if k % 10 == 0:
            for j in range(20):
                scorer.fix(t, f"e{j}", vru_ids[j], float(u[j, 0]), float(u[j, 1]), 2.0)
            scorer.advisory(t, car_ids[k % cars], "brake", 0.03)
        times[k] = (time.perf_counter() - t0) * 1000.0
        cpu[k] = (time.process_time() - c0) * 1000.0
        for arr, speed in ((v, v_speed), (u, u_speed)):
            a = np.radians(arr[:, 2])
            arr[:, 0] += speed * np.sin(a) * DT_S
            arr[:, 1] += speed * np.cos(a) * DT_S
        route += v_speed * DT_S
    return times, cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300)
    args = parser.parse_args()
    info = read_net(district_net())
    print(f"{'cars':>5} {'VRUs':>5} {'p50 ms':>7} {'p90 ms':>7} {'mean ms':>8} {'CPU ms':>7}")
    for cars, vrus in SIZES:
        ms, cpu = run(info, cars, vrus, args.steps)
        p50, p90 = np.percentile(ms, [50, 90])
        print(f"{cars:>5} {vrus:>5} {p50:>7.2f} {p90:>7.2f} {ms.mean():>8.2f} {cpu.mean():>7.2f}")


if __name__ == "__main__":
    main()
