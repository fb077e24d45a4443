"""Ctrl-C during ``rfsas city run``: what was simulated is scored and written (run log,
summary, map), the deployment's processes are stopped over their pipes, exit code 130."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from terminal import ctrl_c_as_at_a_terminal

from rfsas_hw.city.deploy import find_mosquitto
from rfsas_hw.cli.exitcodes import INTERRUPTED
from rfsas_hw.errors import MissingDependencyError

DURATION_S = 600.0
"""Far longer than the test waits: the run ends only by the interrupt."""


def _seconds_logged(log: Path) -> int:
    if not log.exists():
        return 0
    return log.read_text().count('"record": "second"')


def test_ctrl_c_writes_what_was_simulated_and_exits_130(grid_net: Path, tmp_path: Path) -> None:
    try:
        find_mosquitto()
    except MissingDependencyError:
        pytest.skip("mosquitto is not installed (Debian package mosquitto)")
    out = tmp_path / "out"
    args = ["city", "run", "--net", str(grid_net), "--out", str(out), "--rfsas", "both"]
    args += ["--duration", f"{DURATION_S:g}", "--vehicles", "20", "--pedestrians", "30"]
    args += ["--bicycles", "5", "--depart-until", "5", "--origin", "52.4306,13.5325"]
    args += ["--time-scale", "0.5"]
    args += ["--no-png"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "rfsas_hw.cli.main", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=ctrl_c_as_at_a_terminal,
    )
    try:
        # the off run first; then the on run, interrupted once it has stepped a while
        deadline = time.monotonic() + 600
        while _seconds_logged(out / "on.log.jsonl") < 8:
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the on run did not start stepping"
            time.sleep(0.2)
        os.kill(proc.pid, signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == INTERRUPTED, stderr
    assert "interrupted: RF-SAS on after" in stderr, stderr
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr, stderr
    # the off run was whole; the on run's steps until the interrupt are scored and written
    off = json.loads((out / "off.summary.json").read_text())
    assert off["runtime"]["stopped"] == "end"
    doc = json.loads((out / "on.summary.json").read_text())
    runtime, summary = doc["runtime"], doc["summary"]
    assert runtime["stopped"] == "interrupted"
    assert 8.0 <= runtime["simulated_s"] < DURATION_S
    assert summary["duration_s"] == pytest.approx(runtime["simulated_s"], abs=0.11)
    assert runtime["realtime_factor"] > 0
    # the deployment was stopped in order: its processes' counters came back
    assert runtime["counts"]["bearing_messages_sent"] > 0, runtime
    assert not [p for p in runtime["problems"] if "counters" in p], runtime["problems"]
    records = [json.loads(ln) for ln in (out / "on.log.jsonl").read_text().splitlines()]
    assert records[0]["record"] == "start" and records[-1]["record"] == "end"
    assert records[-1]["runtime"]["stopped"] == "interrupted"
    assert (out / "on.map.geojson").exists()
    assert "district run" in stderr  # the table of both runs (on the console, stderr)
    assert "on.summary.json" in stdout
