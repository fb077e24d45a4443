"""The documented ``CsiSource`` example works in a plain script, without a ``__main__`` guard."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("csiread", reason="needs the csi extra (pip install .[csi])")
REPO = Path(__file__).resolve().parents[2]
DATA = REPO / "tests" / "data" / "csi" / "ath_csi_1.dat"

SCRIPT = f"""
from rfsas_hw.sources.csi import CsiSource

src = CsiSource({str(DATA)!r}, rssi_offset_db=-95)
print("frames", sum(len(b) for b in src))
src.close()
"""


@pytest.mark.parametrize("how", ["file", "module"])
def test_csi_source_in_a_script_without_a_main_guard(tmp_path: Path, how: str) -> None:
    script = tmp_path / "plain_csi_script.py"
    script.write_text(SCRIPT)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), str(tmp_path)])}
    cmd = [sys.executable, str(script)] if how == "file" else [sys.executable, "-m", script.stem]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env, check=False)
    assert proc.returncode == 0, proc.stderr
    assert "frames 401" in proc.stdout
    # the script ran once: it was not imported again inside the parsing child
    assert proc.stdout.count("frames") == 1
