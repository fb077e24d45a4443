"""SIGTERM (a service manager's stop) ends the long-running commands as Ctrl-C does:
the backend prints its stats and writes its results and map."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rfsas_hw.link.keys import KeyStore


@pytest.mark.extra("plot")
def test_sigterm_stops_the_backend_with_its_stats_and_outputs(tmp_path: Path) -> None:
    backend = KeyStore.create(tmp_path / "obu-1", "backend")
    backend.trust.enroll(KeyStore.create(tmp_path / "rsu-1", "sensor").card)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out, plot = tmp_path / "run.jsonl", tmp_path / "map.png"
    proc = subprocess.Popen(
        [sys.executable, "-m", "rfsas_hw.cli.main", "backend", "--listen",
         f"udp://127.0.0.1:{port}", "--keys", str(backend.path), "--out", str(out),
         "--plot", str(plot)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not out.exists():
        time.sleep(0.1)  # the results file is opened once the backend runs
    time.sleep(0.5)
    os.kill(proc.pid, signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stderr and "stopped" in stderr
    assert "ran " in stdout and f"wrote {plot}" in stdout
    assert plot.stat().st_size > 1000 and out.exists()
