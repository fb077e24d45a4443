"""``rfsas export`` skips and counts a bad line of any kind (a bit-flipped id, a number
out of range, a negative time, nesting deeper than the parser's stack), writes the
good ones, and fails clearly when nothing in its input can be exported."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "cli"))

from clihelp import run

from rfsas_hw.cli.exitcodes import FAILED, OK

FIX = {
    "record": "fix",
    "t_ns": 1_763_800_000_000_000_000,
    "emitter": "00000000000000aa",
    "x_m": 5.0,
    "y_m": 7.0,
    "cov_xx_m2": 1.0,
    "cov_xy_m2": 0.0,
    "cov_yy_m2": 1.0,
    "ok": True,
    "status": "ok",
    "reason": "",
    "sensors": ["a", "b"],
    "gdop": 1.0,
    "condition": 1.0,
}
BEARING = {
    "record": "bearing",
    "t_ns": 1_763_800_000_000_000_000,
    "sensor_id": "a",
    "emitter": "00000000000000aa",
    "azimuth_deg": 10.0,
    "sigma_deg": 2.0,
    "x_m": 0.0,
    "y_m": 0.0,
    "heading_deg": 0.0,
    "channel": 6,
}
BAD_LINES = [
    json.dumps({**BEARING, "emitter": "0000000000000g0a"}),  # one bit flipped: 'f' -> 'g'
    json.dumps({**BEARING, "azimuth_deg": 1e308}),
    json.dumps({**BEARING, "t_ns": -5}),
    json.dumps({**FIX, "x_m": 1e308}),
    json.dumps({**FIX, "t_ns": -5}),
    json.dumps({**FIX, "t_ns": 2**70}),
    '{"a":' * 100_000 + "1" + "}" * 100_000,
]


@pytest.mark.parametrize("fmt", ["kml", "cot", "geojson", "mcap"])
def test_bad_lines_are_skipped_and_counted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], fmt: str
) -> None:
    if fmt == "mcap":
        pytest.importorskip("mcap", reason="needs the ros2 extra (pip install .[ros2])")
    site = {"record": "site", "origin": {"lat_deg": 52.2, "lon_deg": 0.12, "height_m": 0.0}}
    log = tmp_path / "run.jsonl"
    good = [json.dumps(site), json.dumps(FIX), json.dumps(BEARING)]
    log.write_text("\n".join([*good, *BAD_LINES]) + "\n")
    out = tmp_path / f"run.{fmt}"
    code, stdout, err = run(["export", str(log), "--to", fmt, "-o", str(out)], capsys)
    assert code == OK, err
    assert "Traceback" not in err
    assert "skipped 6 line(s): bad record" in stdout, stdout
    assert "skipped 1 line(s): not JSON" in stdout, stdout
    assert out.stat().st_size > 0
    if fmt == "cot":
        assert 'lat="nan"' not in out.read_text()


def test_a_log_with_nothing_to_export_fails_clearly(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    steps = tmp_path / "sumo.jsonl"  # what `sumo run --out` writes: steps and seeds
    steps.write_text('{"record": "step", "t_s": 0.1}\n{"record": "seed", "seed": 0}\n')
    for fmt in ("kml", "mcap"):
        if fmt == "mcap":
            pytest.importorskip("mcap", reason="needs the ros2 extra (pip install .[ros2])")
        out = tmp_path / f"x.{fmt}"
        args = ["export", str(steps), "--to", fmt, "-o", str(out), "--origin", "52.2,0.12"]
        code, _, err = run(args, capsys)
        assert code == FAILED, err
        assert "nothing to export" in err and "Traceback" not in err
