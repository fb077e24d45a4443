"""Every command exits non-zero when its declared work failed, and says why on stderr;
every ``--help`` lists the exit codes."""

from __future__ import annotations

import json
from pathlib import Path

import click
import pytest
from clihelp import REPO, STILL, run, write_calibration, write_capture

from rfsas_hw.cli.exitcodes import EPILOG, FAILED, OK
from rfsas_hw.cli.main import _load_commands, cli
from rfsas_hw.link.keys import KeyStore


@pytest.fixture
def files(tmp_path: Path) -> dict[str, Path]:
    cal11 = tmp_path / "cal11.yaml"
    cal11.write_text(
        (REPO / "calibration" / "example_cal.yaml").read_text().replace("channel: 6", "channel: 11")
    )
    sensor = KeyStore.create(tmp_path / "rsu-1", "sensor")
    sensor.trust.enroll(KeyStore.create(tmp_path / "rsu-0", "authority").card)
    return {
        "cap": write_capture(tmp_path / "cap.pcap", n=40, span_s=4.0),
        "cal": write_calibration(tmp_path / "cal.yaml"),
        "cal11": cal11,
        "keys": tmp_path / "rsu-1",
        "tmp": tmp_path,
    }


def _swapped_check(tmp: Path) -> Path:
    lines = (REPO / "calibration" / "example_turntable_check.csv").read_text().splitlines()
    head = lines[0].split(",")
    i, j = head.index("rssi1_dbm"), head.index("rssi2_dbm")
    out = [lines[0]]
    for line in lines[1:]:
        cells = line.split(",")
        cells[i], cells[j] = cells[j], cells[i]
        out.append(",".join(cells))
    path = tmp / "swapped.csv"
    path.write_text("\n".join(out) + "\n")
    return path


FAILING: dict[str, list[str]] = {
    "replay, 0 bearings": ["replay", "{cap}", "--calibration", "{cal11}", "--out", "{tmp}/b.csv"],
    "replay, write failed": [
        "replay", "{cap}", *STILL, "--calibration", "{cal}", "--out", "/dev/full",
        "--format", "jsonl"],
    "replay, nothing sent": [
        "replay", "{cap}", *STILL, "--calibration", "{cal}", "--keys", "{keys}",
        "--send", "udp://127.0.0.1:0"],
    "live, 0 bearings": [
        "live", "pcap:{cap}", "--calibration", "{cal11}", "--out", "{tmp}/b.jsonl"],
    "calibrate --check, inconsistent": [
        "calibrate", "--check", "{cal}", "{swapped}"],
    "nonces listen, nothing arrived": [
        "nonces", "listen", "--keys", "{keys}", "--listen", "udp://127.0.0.1:0",
        "--duration", "0.2"],
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(FAILING))
def test_a_command_whose_work_failed_exits_1(
    case: str, files: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    if "/dev/full" in FAILING[case] and not Path("/dev/full").exists():
        pytest.skip("needs /dev/full")
    names = {**{k: str(v) for k, v in files.items()}, "swapped": str(_swapped_check(files["tmp"]))}
    args = [a.format(**names) for a in FAILING[case]]
    code, _, err = run(args, capsys)
    assert code == FAILED, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("failed: ") and "Traceback" not in err


def test_the_same_runs_succeed_when_the_work_is_done(
    files: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run(
        ["replay", str(files["cap"]), *STILL, "--calibration", str(files["cal"]), "--json",
         "--out", str(files["tmp"] / "b.csv")],
        capsys,
    )  # fmt: skip
    assert code == OK, err
    assert json.loads(out)["ok"] is True


def _commands(group: click.Command, path: str = "rfsas") -> list[tuple[str, click.Command]]:
    found = [(path, group)]
    if isinstance(group, click.Group):
        for name, sub in sorted(group.commands.items()):
            found += _commands(sub, f"{path} {name}")
    return found


def test_every_help_lists_the_exit_codes() -> None:
    _load_commands()
    for name, command in _commands(cli):
        assert command.epilog and "Exit codes" in command.epilog, name
    assert "130 interrupted" in EPILOG and "2 bad input" in EPILOG
