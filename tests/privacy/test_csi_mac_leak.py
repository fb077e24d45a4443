"""No raw MAC leaves a sensor reading CSI: ``rfsas -vv replay csi:…`` output, stdout and log."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
from privhelp import CALIBRATION, KNOWN_MACS, STILL
from test_mac_leak import find_leaks

from rfsas_hw.df.interferometer import C_MPS
from rfsas_hw.twin.csi_writer import CsiArray, synth_csi, write_feitcsi


def test_csi_replay_leaks_no_mac(tmp_path: Path) -> None:
    n = 120
    rng = np.random.default_rng(3)
    macs = np.array(KNOWN_MACS, np.uint64)[rng.integers(0, len(KNOWN_MACS), n)]
    theta = rng.uniform(-20, 20, n)
    h = synth_csi(CsiArray(C_MPS / 2437e6 / 2), theta, 2437, np.full((n, 2), 30.0), seed=4)
    rssi = np.column_stack([-55 - theta / 5, -55 + theta / 5]).round()
    capture = tmp_path / "known.csi"
    write_feitcsi(capture, np.arange(n) * 10_000_000, macs, rssi, h)
    assert all(int(m).to_bytes(6, "big") in capture.read_bytes() for m in set(macs.tolist()))
    out = tmp_path / "bearings.jsonl"
    cmd = [sys.executable, "-m", "rfsas_hw.cli.main", "-vv", "replay", f"csi:{capture}?freq=2437"]
    cmd += [*STILL, "--calibration", str(CALIBRATION), "--out", str(out)]
    proc = subprocess.run(cmd, capture_output=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")
    assert len(out.read_text().splitlines()) == n
    blobs = {"stdout": proc.stdout, "stderr": proc.stderr, "jsonl": out.read_bytes()}
    assert find_leaks(blobs, KNOWN_MACS) == []
