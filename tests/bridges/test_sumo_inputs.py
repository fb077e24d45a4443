"""SUMO inputs that could hang or crash a run are refused with one line before SUMO
starts: a DTD (entity expansion) in any file SUMO reads, an unbounded seed count,
NaN or negative settings, non-finite FCD samples."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "cli"))

from clihelp import REPO, run

from rfsas_hw.cli.exitcodes import BAD_INPUT

LAUGHS = (
    '<?xml version="1.0"?>\n<!DOCTYPE configuration [\n<!ENTITY a "aaaaaaaaaa">\n'
    + "".join(
        f'<!ENTITY {n} "{("&" + p + ";") * 10}">\n'
        for p, n in zip("abcdefgh", "bcdefghi", strict=True)
    )
    + "]>\n"
)


@pytest.fixture
def scenario(tmp_path: Path) -> Path:
    shutil.copytree(REPO / "examples" / "sumo", tmp_path / "sumo")
    return tmp_path / "sumo"


def _expect_refusal(args: list[str], capsys: pytest.CaptureFixture[str], words: str) -> None:
    code, _, err = run(args, capsys)
    assert code == BAD_INPUT, err
    assert words in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize("victim", ["crossing.sumocfg", "crossing.net.xml", "crossing.rou.xml"])
def test_a_dtd_in_any_file_sumo_reads_is_refused(
    scenario: Path, capsys: pytest.CaptureFixture[str], victim: str
) -> None:
    path = scenario / victim
    body = path.read_text().split("?>", 1)[1]
    path.write_text(LAUGHS + body)
    _expect_refusal(
        ["sumo", "run", str(scenario / "crossing.sumocfg")], capsys, "document type declaration"
    )


def test_a_seed_count_is_bounded(scenario: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["sumo", "run", str(scenario / "crossing.sumocfg"), "--seeds", "1000000000"]
    _expect_refusal(args, capsys, "at most")


@pytest.mark.parametrize(
    ("old", "new"),
    [
        ("hold_s: 1.0", "hold_s: -1.0"),
        ("hold_s: 1.0", "hold_s: .nan"),
        ("x_m: -7.0, y_m: 7.0", "x_m: .nan, y_m: 7.0"),
    ],
)
def test_nan_and_negative_settings_are_refused(
    scenario: Path, capsys: pytest.CaptureFixture[str], old: str, new: str
) -> None:
    units = scenario / "units.yaml"
    text = units.read_text()
    assert old in text
    units.write_text(text.replace(old, new, 1))
    code, _, err = run(["sumo", "run", str(scenario / "crossing.sumocfg")], capsys)
    assert code == BAD_INPUT and "Traceback" not in err, err
    assert "units.yaml" in err


SAMPLES = {
    "nan x": '<vehicle id="ego" x="nan" y="100.0" angle="90.0" length="4.5"/>',
    "inf length": '<vehicle id="ego" x="90.0" y="100.0" angle="90.0" length="inf"/>',
    "DTD": '<vehicle id="ego" x="90.0" y="100.0" angle="90.0" length="4.5"/>',
}


@pytest.mark.parametrize("bad", sorted(SAMPLES))
def test_fcd_samples_that_are_not_finite_are_refused(
    scenario: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], bad: str
) -> None:
    head = LAUGHS if bad == "DTD" else '<?xml version="1.0"?>\n'
    words = "document type declaration" if bad == "DTD" else "finite"
    fcd = tmp_path / "fcd.xml"
    body = f'<fcd-export><timestep time="0.0">{SAMPLES[bad]}</timestep></fcd-export>\n'
    fcd.write_text(head + body)
    out = tmp_path / "s.yaml"
    args = ["sumo", "fcd", str(fcd), "--units", str(scenario / "units.yaml"), "-o", str(out)]
    _expect_refusal(args, capsys, words)
    assert not out.exists()


def test_a_net_sumo_refuses_ends_with_sumos_reason(
    scenario: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """libsumo says only "Process Error"; SUMO's own reason ends the message instead."""
    pytest.importorskip("libsumo", reason="needs the sumo extra")
    net = scenario / "crossing.net.xml"
    net.write_text(net.read_text().replace('from="A0" to="bottom0"', 'from="nowhere" to="bottom0"'))
    # file-descriptor capture: libsumo writes to descriptor 2 itself
    code, _, err = run(["sumo", "run", str(scenario / "crossing.sumocfg")], capfd)
    assert code != 0 and "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert "SUMO did not start" in last and "Unknown from-node 'nowhere'" in last, err
    assert "Process Error" not in last
    # SUMO's own lines did not go to the console around it
    assert not [line for line in err.splitlines() if line.startswith("Error:")], err
