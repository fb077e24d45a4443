"""Cost of the ROS 2 scene per backend step, beside the JSONL run log rfsas writes anyway.

A backend step with E tracked emitters seen by two sensors is recorded by
each output for STEPS steps; the table gives milliseconds per step and bytes
per step. ``scene only`` builds and serialises the messages without writing
(the share every ROS 2 output pays once, however many outputs there are).

    python bench/bench_ros2.py [--steps 200]
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from rfsas_hw.backend.service import JsonlSink
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.records import Assessment, BearingBatch, Fix, Pose
from rfsas_hw.ros2.bag import McapFileWriter, Rosbag2Writer
from rfsas_hw.ros2.sink import BackendScene, SceneSink
from rfsas_hw.ros2.topics import Topic

NS = 1_000_000_000
T0 = 1_763_800_000 * NS
SENSORS = {"rsu-1": Pose(-20.0, -12.0, 30.0), "rsu-2": Pose(22.0, -10.0, 320.0)}


class Discard:
    """A writer that keeps only the byte count."""

    def __init__(self) -> None:
        self.bytes = 0

    def write(self, topic: Topic, log_time_ns: int, data: bytes) -> None:
        self.bytes += len(data)

    def close(self) -> None:
        pass


def records(
    k: int, n: int, rng: np.random.Generator
) -> tuple[list[Any], list[Fix], list[Assessment]]:
    t = T0 + k * NS // 10
    ids = np.arange(1, n + 1, dtype=np.uint64) * np.uint64(0x9E3779B97F4A7C15 % 2**63)
    batches = [
        (
            BearingBatch(
                sid,
                np.full(n, t - NS // 20, np.int64),
                rng.uniform(0, 360, n),
                np.full(n, 1.5),
                rng.uniform(10, 30, n),
                np.full(n, 6, np.int16),
                ids,
            ),
            pose,
        )
        for sid, pose in SENSORS.items()
    ]
    fixes, assessments = [], []
    for e in ids.tolist():
        x, y = rng.uniform(-30, 30, 2)
        fixes.append(
            Fix(
                t,
                f"{e:016x}",
                x,
                y,
                0.4,
                0.05,
                0.3,
                True,
                "ok",
                "ok: 2 bearings",
                ("rsu-1", "rsu-2"),
                1.4,
                1.3,
            )
        )
        assessments.append(
            Assessment(
                t,
                f"{e:016x}",
                x,
                y,
                0.4,
                0.05,
                0.3,
                1.2,
                0.1,
                0.05,
                ("rsu-1", "rsu-2"),
                True,
                "ok",
                0.02,
                2.5,
                20.0,
                0.0,
                0.001,
                2e-5,
                "clear",
                ("risk 2e-05",),
                False,
            )
        )
    return batches, fixes, assessments


def run(kind: str, steps: int, n: int, tmp: Path) -> tuple[float, int]:
    rng = np.random.default_rng(1)
    vehicle = VehicleState(x_m=0.0, y_m=-40.0, heading_deg=0.0, speed_mps=8.0, t_ns=T0)
    data = [records(k, n, rng) for k in range(1, steps + 1)]
    stations = dict(SENSORS)
    discard = Discard()
    sinks: list[Any] = []
    if kind == "jsonl run log":
        sinks.append(JsonlSink(tmp / "run.jsonl", bearings=True))
        size = lambda: (tmp / "run.jsonl").stat().st_size  # noqa: E731
    else:
        writer: Any = {
            "scene only": lambda: discard,
            "mcap file": lambda: McapFileWriter(tmp / "run.mcap"),
            "rosbag2 sqlite3": lambda: Rosbag2Writer(tmp / "bag", overwrite=True),
        }[kind]()
        sinks.append(
            BackendScene(
                SceneSink([writer]),
                stations=lambda: stations,
                vehicle=lambda: vehicle,
                link=lambda: (False, {"verified": 1}),
            )
        )
        size = {
            "scene only": lambda: discard.bytes,
            "mcap file": lambda: (tmp / "run.mcap").stat().st_size,
            "rosbag2 sqlite3": lambda: sum(p.stat().st_size for p in (tmp / "bag").iterdir()),
        }[kind]
    t0 = time.perf_counter()
    for batches, fixes, assessments in data:
        for sink in sinks:
            for batch, pose in batches:
                sink.on_bearings(batch, pose)
            sink.on_results(fixes, assessments)
    for sink in sinks:
        sink.close()
    return (time.perf_counter() - t0) / steps * 1e3, size() // steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200)
    args = parser.parse_args()
    kinds = ["jsonl run log", "scene only", "mcap file", "rosbag2 sqlite3"]
    print(f"{'emitters':>8} {'output':<16} {'ms/step':>8} {'bytes/step':>11}")
    for n in (1, 10, 50):
        for kind in kinds:
            tmp = Path(tempfile.mkdtemp())
            try:
                run(kind, 5, n, tmp)  # warm-up: imports, type generation
                best = min((run(kind, args.steps, n, tmp) for _ in range(2)), key=lambda r: r[0])
            finally:
                shutil.rmtree(tmp, ignore_errors=True)
            ms, size = best
            print(f"{n:>8} {kind:<16} {ms:>8.2f} {size:>11,}")


if __name__ == "__main__":
    main()
