"""``sumo run --send``: bearings that could not be sent are counted and end the run with
exit code 1, naming each unit, instead of a silent 0."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "cli"))

from clihelp import REPO, run

from rfsas_hw.cli.exitcodes import FAILED
from rfsas_hw.link.keys import KeyStore

pytest.importorskip("libsumo", reason="needs the sumo extra (pip install .[sumo])")


def test_every_send_failing_is_a_failed_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    shutil.copytree(REPO / "examples" / "sumo", tmp_path / "sumo")
    units = tmp_path / "sumo" / "units.yaml"
    # the ego departs at 8.6 s; sending paces the run to the wall clock
    units.write_text(units.read_text().replace("end_s: 30.0", "end_s: 9.5"))
    for unit in ("rsu-nw", "rsu-ne", "rsu-se", "ego-unit"):
        KeyStore.create(tmp_path / "keys" / unit, "sensor", unit)
    # a broadcast address without SO_BROADCAST: every sendto fails (EACCES)
    args = ["sumo", "run", str(tmp_path / "sumo" / "crossing.sumocfg")]
    args += ["--send", "udp://255.255.255.255:47000", "--keys", str(tmp_path / "keys")]
    code, out, err = run(args, capsys)
    assert code == FAILED, err
    assert "sent 0 bearings" in out
    last = err.strip().splitlines()[-1]
    assert last.startswith("failed:") and "rsu-nw:" in last and "not sent" in last
