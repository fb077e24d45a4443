"""Bearings-fed tracks of a standing person as the car closes in: bias and consistency.

    python bench/bench_bearing_tracking.py [--runs 200]

A person stands at (0, −2.25) m, 0.5 m outside the lane; the car's unit drives
along the lane centre (y = 0) at 60 km/h from x = −60 m, a roadside unit stands
at (4, 7) m (the Euro NCAP matrix's pose); both measure the person's bearing
every 0.1 s with 6° (one sigma, about the matrix's units with their site floor).
For each tracker the table gives, by the car's distance to the person, the
position NEES (2 when the covariance is right), the mean and RMS error across
the road and the mean and RMS speed across it (positive: towards the lane).
Trackers: fed by fixes (the backend's default), fed by bearings with the EKF,
with the start fix's sigma doubled (the matrix's profile), and iterated.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from rfsas_hw.backend.association import AssociationConfig
from rfsas_hw.backend.bearing_tracking import BearingUpdateConfig
from rfsas_hw.backend.service import BackendConfig, BackendService
from rfsas_hw.backend.triangulation import TriangulationOptions
from rfsas_hw.records import BearingBatch, Pose

NS_PER_S = 1_000_000_000
PERSON = np.array([0.0, -2.25])
RSU = np.array([4.0, 7.0])
SPEED_MPS = 60 / 3.6
SIGMA_DEG = 6.0
BANDS_M = ((30.0, 20.0), (20.0, 10.0), (10.0, 5.0), (5.0, 2.3))
TRACKERS: dict[str, BackendConfig] = {
    name: BackendConfig(
        association=AssociationConfig(window_s=0.5),
        triangulation=TriangulationOptions(max_range_fraction=0.3),
        tracking="fixes" if name == "fixes" else "bearings",
        bearings=bearings,
    )
    for name, bearings in (
        ("fixes", BearingUpdateConfig()),
        ("bearings, EKF", BearingUpdateConfig()),
        ("bearings, EKF, start σ × 2", BearingUpdateConfig(start_sigma_scale=2.0)),
        ("bearings, iterated (3)", BearingUpdateConfig(iterations=3)),
    )
}


def _bearing(sensor: str, t_ns: int, azimuth_deg: float) -> BearingBatch:
    return BearingBatch(
        sensor_id=sensor,
        t_ns=np.array([t_ns], np.int64),
        azimuth_deg=np.array([azimuth_deg % 360.0]),
        sigma_deg=np.array([SIGMA_DEG]),
        snr_db=np.array([20.0]),
        channel=np.array([6], np.int16),
        emitter=np.array([1], np.uint64),
    )


def run(config: BackendConfig, runs: int, seed: int) -> dict[tuple[float, float], np.ndarray]:
    """Per distance band, rows of (NEES, error across the road m, speed across m/s)."""
    rng = np.random.default_rng(seed)
    rows: dict[tuple[float, float], list[tuple[float, float, float]]] = {b: [] for b in BANDS_M}
    for _ in range(runs):
        svc = BackendService(config)
        for k in range(36):
            t = k * NS_PER_S // 10
            car = np.array([-60.0 + SPEED_MPS * k * 0.1, 0.0])
            for sensor, pos in (("rsu", RSU), ("car", car)):
                d = PERSON - pos
                az = math.degrees(math.atan2(d[0], d[1])) + SIGMA_DEG * rng.standard_normal()
                svc.on_bearings(_bearing(sensor, t, az), Pose(float(pos[0]), float(pos[1]), 90.0))
            svc.step(t + 1)
            track = svc.tracker.tracks.get(1)
            distance = float(np.hypot(*(PERSON - car)))
            band = next((b for b in BANDS_M if b[1] <= distance < b[0]), None)
            if track is None or band is None:
                continue
            e = track.position - PERSON
            nees = float(e @ np.linalg.solve(track.position_cov, e))
            rows[band].append((nees, float(e[1]), float(track.velocity[1])))
    return {b: np.array(r).reshape(-1, 3) for b, r in rows.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=200)
    parser.add_argument("--seed", type=int, default=5)
    args = parser.parse_args()
    print("tracker | car to person | NEES | across: mean, RMS (m) | speed across: mean, RMS (m/s)")
    for name, config in TRACKERS.items():
        for (far, near), a in run(config, args.runs, args.seed).items():
            if not len(a):
                print(f"{name} | {far:g}–{near:g} m | no track")
                continue
            rms = np.sqrt(np.mean(a**2, axis=0))
            print(
                f"{name} | {far:g}–{near:g} m | {a[:, 0].mean():.2f} | "
                f"{a[:, 1].mean():+.2f}, {rms[1]:.2f} | {a[:, 2].mean():+.2f}, {rms[2]:.2f}"
            )


if __name__ == "__main__":
    main()
