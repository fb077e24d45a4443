"""``rfsas export`` streams: memory does not grow with the run log, and an export that
spills to temporary files writes the same file as one that fits in memory."""

from __future__ import annotations

import json
import pickle
import random
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import pytest

from rfsas_hw.exports import export_run, scene, spill
from rfsas_hw.exports.run import RunLog
from rfsas_hw.exports.spill import ExternalSort, Spool

T0 = 1_767_268_800_000_000_000  # 2026-01-01T12:00:00Z
MS = 1_000_000
SITE = {"record": "site", "origin": {"lat_deg": 52.2053, "lon_deg": 0.1218, "height_m": 12.0}}
SENSORS = {"rsu-a": (-30.0, 10.0, 90.0), "rsu-b": (25.0, -20.0, 0.0)}


def _lines(k: int) -> list[dict[str, object]]:
    """One backend step: a bearing per sensor, a fix and an untracked assessment (no
    velocity: an emitter seen once, so no track grows with the log)."""
    t_ns = T0 + k * 100 * MS
    emitter = f"{k % 7:016x}"
    out: list[dict[str, object]] = []
    # a little out of time order, as bearings of several sensors arrive
    for i, (sid, (x, y, heading)) in enumerate(SENSORS.items()):
        out.append(
            {
                "record": "bearing",
                "t_ns": t_ns + (3 - 2 * i) * MS,
                "sensor_id": sid,
                "emitter": emitter,
                "azimuth_deg": (37.0 * k + 90 * i) % 360.0,
                "sigma_deg": 1.5,
                "x_m": x,
                "y_m": y,
                "heading_deg": heading,
                "snr_db": 18.0,
                "channel": 6,
            }
        )
    x, y = 10.0 * ((k % 11) - 5), 5.0 * ((k % 13) - 6)
    out.append(
        {
            "record": "fix",
            "t_ns": t_ns,
            "emitter": emitter,
            "x_m": x,
            "y_m": y,
            "cov_xx_m2": 1.0 + k % 3,
            "cov_xy_m2": 0.2,
            "cov_yy_m2": 2.0,
            "ok": True,
            "status": "ok",
            "reason": "",
            "sensors": list(SENSORS),
            "gdop": 1.2,
            "condition": 2.0,
        }
    )
    out.append(
        {
            "record": "assessment",
            "t_ns": t_ns,
            "emitter": emitter,
            "x_m": x,
            "y_m": y,
            "cov_xx_m2": 1.0,
            "cov_xy_m2": 0.2,
            "cov_yy_m2": 2.0,
            "vx_mps": None,
            "vy_mps": None,
            "age_s": 0.05,
            "sensors": list(SENSORS),
            "fix_ok": True,
            "fix_reason": "ok",
            "p_collision": None,
            "t_closest_s": None,
            "distance_to_contact_m": None,
            "impact_speed_mps": None,
            "fatality_risk": None,
            "risk": None,
            "advisory": "none",
            "reasons": [],
            "link_alarm": False,
        }
    )
    return out


LINES_PER_STEP = 4
"""Lines :func:`_lines` gives a step."""


def write_log(path: Path, steps: int) -> Path:
    with path.open("w") as f:
        f.write(json.dumps(SITE) + "\n")
        for k in range(steps):
            f.writelines(json.dumps(d) + "\n" for d in _lines(k))
    return path


def _map(fmt: str) -> Callable[[Path, Path], object]:
    return lambda log, out: export_run(log, fmt, out)


def _cpm(log: Path, out: Path) -> object:
    pytest.importorskip("asn1tools", reason="needs the v2x extra (pip install .[v2x])")
    from rfsas_hw.v2x.export import export_cpm_pcap

    return export_cpm_pcap(log, out)


def _rosbag2(log: Path, out: Path) -> object:
    pytest.importorskip("rosbags", reason="needs the ros2 extra (pip install .[ros2])")
    from rfsas_hw.ros2.export import export_runs

    return export_runs([log], out, "rosbag2")


TARGETS: dict[str, Callable[[Path, Path], object]] = {
    "geojson": _map("geojson"),
    "kml": _map("kml"),
    "cot": _map("cot"),
    "cpm": _cpm,
    "rosbag2": _rosbag2,
}


@pytest.fixture
def small_budgets(monkeypatch: pytest.MonkeyPatch) -> None:
    """Budgets small enough that a log of a few thousand lines spills many times."""
    monkeypatch.setattr(spill, "SPILL_BYTES", 4 * 1024)
    monkeypatch.setattr(spill, "BLOCK", 4 * 1024)
    monkeypatch.setattr(spill, "FAN_IN", 4)
    monkeypatch.setattr(scene, "CHUNK", 16)


def _peak(export: Callable[[Path, Path], object], log: Path, out: Path) -> int:
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        base, _ = tracemalloc.get_traced_memory()
        export(log, out)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return peak - base


TRACED_TARGETS = sorted(set(TARGETS) - {"rosbag2"})
"""The ROS 2 exports sort pickled slotted dataclasses; under tracemalloc each unpickled
record leaves small tuples counted as alive (about 0.7 kB a step here) while the process's
RSS stays flat, so their memory is measured by ``bench/bench_export.py`` instead."""


@pytest.mark.parametrize("fmt", TRACED_TARGETS)
@pytest.mark.usefixtures("small_budgets")
def test_memory_does_not_grow_with_the_log(fmt: str, tmp_path: Path) -> None:
    export = TARGETS[fmt]
    short = write_log(tmp_path / "short.jsonl", 80)
    long = write_log(tmp_path / "long.jsonl", 320)
    export(write_log(tmp_path / "warm.jsonl", 10), tmp_path / "warm.out")  # imports, caches
    small = _peak(export, short, tmp_path / "short.out")
    large = _peak(export, long, tmp_path / "long.out")
    # Reading the log whole keeps a record object per line (144 bytes for a fix before
    # its numbers); streaming keeps budgets that do not depend on the log
    added_lines = (320 - 80) * LINES_PER_STEP
    assert (large - small) / added_lines < 100, (small, large)


@pytest.mark.parametrize("fmt", ["geojson", "kml", "cot", "cpm"])
def test_an_export_that_spills_writes_the_same_file(
    fmt: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    log = write_log(tmp_path / "run.jsonl", 60)
    TARGETS[fmt](log, tmp_path / "in_memory.out")
    made: list[int] = []
    temporary = spill._temporary
    monkeypatch.setattr(spill, "SPILL_BYTES", 4 * 1024)
    monkeypatch.setattr(spill, "_temporary", lambda: made.append(1) or temporary())
    TARGETS[fmt](log, tmp_path / "spilled.out")
    assert made  # the budget was exceeded: this export went through temporary files
    assert (tmp_path / "spilled.out").read_bytes() == (tmp_path / "in_memory.out").read_bytes()


def test_the_sort_is_stable_and_keeps_its_budget() -> None:
    rng = random.Random(5)
    items = [((rng.randrange(50), rng.randrange(3)), pickle.dumps(i)) for i in range(3000)]
    with ExternalSort(max_bytes=8 * 1024) as s:
        for key, data in items:
            s.add(key, data)
        out = list(s.sorted())
        assert s.spilled > 10 and s.count == len(items)
    assert out == [data for _, data in sorted(items, key=lambda item: item[0])]


def test_a_spool_gives_back_what_was_written() -> None:
    pieces = [bytes([i % 256]) * (i % 97 + 1) for i in range(500)]
    with Spool(max_bytes=1000) as sp:
        for p in pieces:
            sp.write(p)
        assert sp._file is not None  # beyond the budget: on disk
        assert b"".join(sp.blocks()) == b"".join(pieces)
    with Spool() as sp:
        sp.write(b"abc")
        assert sp._file is None and b"".join(sp.blocks()) == b"abc"


def test_the_log_is_read_as_it_is_taken(tmp_path: Path) -> None:
    log = write_log(tmp_path / "run.jsonl", 50)
    with log.open("a") as f:
        f.write("not json\n")
    run = RunLog(str(log))
    records = run.records()
    first = next(records)
    assert first.t_ns > 0 and not run.skipped  # the bad last line is not read yet
    assert sum(1 for _ in records) == 50 * 4 - 1
    assert run.skipped == {"not JSON": 1} and run.origin is not None
