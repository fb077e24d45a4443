"""Peak memory and wall time of ``rfsas export`` per target on a large run log.

    python bench/bench_export.py [--mb 250] [--to geojson,kml,cot,cpm,mcap,rosbag2]

A backend run (three sensors, four walking emitters, 10 Hz bearings, a step
every 0.1 s) is recorded through the backend's own JSON-lines sink, then
repeated with later times until the log holds ``--mb`` megabytes (a site line
once, then bearings, fixes and assessments as a long run writes them). Each
target is exported by ``rfsas export`` in a child process under
``/usr/bin/time -v``; the table gives its peak resident set size and wall
time, and the output's size. Numbers are from this one run on a possibly
shared machine.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from rfsas_hw.angles import math_rad_to_compass
from rfsas_hw.backend.service import BackendConfig, BackendService, JsonlSink
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.records import BearingBatch, Pose

NS = 1_000_000_000
T0 = 1_767_268_800 * NS  # 2026-01-01T12:00:00Z
ORIGIN = SiteOrigin(52.2053, 0.1218, 12.0)
SENSORS = {
    "rsu-a": Pose(-30.0, 10.0, 90.0),
    "rsu-b": Pose(25.0, -20.0, 0.0),
    "rsu-c": Pose(5.0, 35.0, 180.0),
}
EMITTERS = (0x0123_4567_89AB_CDEF, 0x1111_2222_3333_4444, 0x5555_6666_7777_8888, 0x0A0B0C0D)
BASE_S = 60.0
"""Length of the recorded base run, seconds (the log repeats it)."""
TARGETS = ("geojson", "kml", "cot", "cpm", "mcap", "rosbag2")


def base_run(path: Path) -> None:
    """Record :data:`BASE_S` seconds of a backend run with bearings and a site line."""
    sink = JsonlSink(path, origin=ORIGIN, bearings=True)
    service = BackendService(BackendConfig(), sinks=[sink], clock=lambda: T0)
    rng = np.random.default_rng(3)
    for k in range(int(BASE_S * 10)):
        t_s = k / 10
        t_ns = T0 + k * NS // 10
        for i, emitter in enumerate(EMITTERS):
            phase = t_s / 20 + i * math.pi / 2
            target = np.array([25.0 * math.cos(phase), 25.0 * math.sin(phase)])
            for sid, pose in SENSORS.items():
                d = target - np.array([pose.x_m, pose.y_m])
                az = float(math_rad_to_compass(np.arctan2(d[1], d[0]))) + rng.normal(0, 1.0)
                service.on_bearings(
                    BearingBatch(
                        sid,
                        np.array([t_ns + i], np.int64),
                        np.array([az % 360.0]),
                        np.array([1.5]),
                        np.array([18.0]),
                        np.array([6], np.int16),
                        np.array([emitter], np.uint64),
                    ),
                    pose,
                )
        service.step(now_ns=t_ns + NS // 20)
    service.close()


def long_log(base: Path, out: Path, megabytes: float) -> tuple[int, int]:
    """Repeat ``base`` with later times into ``out`` until it holds ``megabytes``;
    (lines, bytes) written."""
    lines = [json.loads(line) for line in base.read_text().splitlines() if line.strip()]
    site = [d for d in lines if d.get("record") == "site"]
    body = [d for d in lines if d.get("record") in ("bearing", "fix", "assessment")]
    span_ns = int(BASE_S * NS)
    limit = int(megabytes * 1e6)
    written = n = 0
    with out.open("w", encoding="utf-8") as f:
        for d in site:
            text = json.dumps(d) + "\n"
            f.write(text)
            written += len(text)
            n += 1
        copy = 0
        while written < limit:
            for d in body:
                text = json.dumps({**d, "t_ns": d["t_ns"] + copy * span_ns}) + "\n"
                f.write(text)
                written += len(text)
                n += 1
            copy += 1
    return n, written


def measure(log: Path, fmt: str, workdir: Path) -> tuple[float, float, int, str]:
    """(peak RSS MB, wall s, output bytes, last summary line) of one export."""
    out = workdir / ("out_bag" if fmt == "rosbag2" else f"out.{fmt}")
    if out.is_dir():
        shutil.rmtree(out)
    else:
        out.unlink(missing_ok=True)
    cmd = [sys.executable, "-m", "rfsas_hw.cli.main", "export", str(log), "--to", fmt]
    cmd += ["--out", str(out)]
    proc = subprocess.run(
        ["/usr/bin/time", "-v", *cmd], capture_output=True, text=True, timeout=3600, check=False
    )
    if proc.returncode != 0:
        raise SystemExit(f"{fmt}: exit {proc.returncode}: {proc.stderr[-2000:]}")
    rss_kb = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", proc.stderr)[1])  # type: ignore[index]
    wall = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): ([\d:.]+)", proc.stderr)
    parts = [float(p) for p in wall[1].split(":")]  # type: ignore[index]
    seconds = sum(p * 60**i for i, p in enumerate(reversed(parts)))
    size = (
        sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
        if out.is_dir()
        else out.stat().st_size
    )
    first = proc.stdout.splitlines()[0] if proc.stdout else ""
    return rss_kb / 1024, seconds, size, first


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mb", type=float, default=250.0, help="size of the log, MB")
    parser.add_argument("--to", default=",".join(TARGETS), help="targets, comma-separated")
    parser.add_argument("--keep", type=Path, help="keep the log and outputs in this directory")
    args = parser.parse_args()
    workdir = args.keep or Path(tempfile.mkdtemp(prefix="bench_export."))
    workdir.mkdir(parents=True, exist_ok=True)
    try:
        log = workdir / "long.jsonl"
        if not log.exists():
            base = workdir / "base.jsonl"
            base_run(base)
            n, size = long_log(base, log, args.mb)
            print(f"log: {n:,} lines, {size / 1e6:.0f} MB")
        else:
            print(f"log: {log.stat().st_size / 1e6:.0f} MB (kept from an earlier run)")
        print(f"{'target':<8} {'peak RSS MB':>11} {'wall s':>7} {'output MB':>9}  summary")
        for fmt in args.to.split(","):
            rss, wall, size, summary = measure(log, fmt, workdir)
            print(f"{fmt:<8} {rss:>11.0f} {wall:>7.1f} {size / 1e6:>9.1f}  {summary}")
    finally:
        if args.keep is None:
            shutil.rmtree(workdir, ignore_errors=True)


if __name__ == "__main__":
    main()
