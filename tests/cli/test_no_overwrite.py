"""No command writes over its input, outside its output, or over an existing output
without ``--force``; what decides trust is protected like a private key."""

from __future__ import annotations

import importlib.util
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
from clihelp import REPO, run, write_calibration, write_capture
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rfsas_hw.cli.exitcodes import BAD_INPUT, OK
from rfsas_hw.errors import KeyStoreError
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.outpaths import check_output, inside, safe_name

TURNTABLE = REPO / "calibration" / "example_turntable.csv"
CHECK = REPO / "calibration" / "example_turntable_check.csv"


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("inputs")
    write_capture(d / "cap.pcap", n=60, span_s=6.0)
    write_calibration(d / "cal.yaml")
    shutil.copy(TURNTABLE, d / "sweep.csv")
    shutil.copy(CHECK, d / "check.csv")
    (d / "run.jsonl").write_text('{"record": "stats"}\n')
    (d / "model.zip").write_bytes(b"PK\x05\x06" + bytes(18))  # a trained policy, as far as names go
    return d


# Every command that writes a file, with the inputs it reads and where its output goes.
# ``{out}`` is replaced by the path under test.
COMMANDS: list[tuple[str, list[str], list[str]]] = [
    ("replay", ["cap.pcap", "cal.yaml"],
     ["replay", "cap.pcap", "--calibration", "cal.yaml", "--out", "{out}", "--format", "jsonl"]),
    ("live", ["cap.pcap", "cal.yaml"],
     ["live", "pcap:cap.pcap", "--calibration", "cal.yaml", "--out", "{out}", "--format", "csv"]),
    ("calibrate", ["sweep.csv"], ["calibrate", "sweep.csv", "-o", "{out}"]),
    ("calibrate --plot", ["sweep.csv"],
     ["calibrate", "sweep.csv", "-o", "new.yaml", "--plot", "{out}"]),
    ("calibrate --check -o", ["cal.yaml", "check.csv"],
     ["calibrate", "--check", "cal.yaml", "check.csv", "-o", "{out}"]),
    ("sim evaluate --csv", ["model.zip"],
     ["sim", "evaluate", "--model", "model.zip", "--csv", "{out}"]),
    ("sim render", ["model.zip"], ["sim", "render", "--model", "model.zip", "--output", "{out}"]),
    ("export", ["run.jsonl"],
     ["export", "run.jsonl", "--to", "kml", "--origin", "52.2,0.12", "-o", "{out}"]),
]  # fmt: skip

if importlib.util.find_spec("gymnasium") is None:
    # without the sim extra these commands cannot run; test_sim_commands_are_covered
    # is skipped then, naming the extra
    COMMANDS = [c for c in COMMANDS if not c[0].startswith("sim ")]

ALIASES: dict[str, Callable[[Path, Path], Path]] = {
    "same path": lambda d, p: p,
    "relative with ..": lambda d, p: d / "sub" / ".." / p.name,
    "hard link": lambda d, p: _link(d, p, os.link),
    "symlink": lambda d, p: _link(d, p, os.symlink),
}


def _link(d: Path, target: Path, make: Callable[[Path, Path], None]) -> Path:
    alias = d / f"alias-{make.__name__}-{target.name}"
    if not alias.exists() and not alias.is_symlink():
        make(target, alias)
    return alias


@settings(
    max_examples=30,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(
    command=st.sampled_from(COMMANDS),
    pick=st.integers(0, 5),
    alias=st.sampled_from(sorted(ALIASES)),
    force=st.booleans(),
)
def test_no_command_writes_over_any_of_its_inputs(
    workdir: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    command: tuple[str, list[str], list[str]],
    pick: int,
    alias: str,
    force: bool,
) -> None:
    monkeypatch.chdir(workdir)
    (workdir / "sub").mkdir(exist_ok=True)
    _, inputs, template = command
    victim = workdir / inputs[pick % len(inputs)]
    out = ALIASES[alias](workdir, victim)
    before = {name: (workdir / name).read_bytes() for name in inputs}
    args = [str(out) if a == "{out}" else a for a in template] + (["--force"] if force else [])
    code, _, err = run(args, capsys)
    assert code == BAD_INPUT, err
    assert "is also an input" in err and "Traceback" not in err
    assert {name: (workdir / name).read_bytes() for name in inputs} == before


def test_calibrate_refuses_an_existing_table_without_force(
    workdir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "cal.yaml"
    out.write_text("mine\n")
    args = ["calibrate", str(workdir / "sweep.csv"), "-o", str(out)]
    code, _, err = run(args, capsys)
    assert code == BAD_INPUT and "--force" in err and out.read_text() == "mine\n"
    code, _, err = run([*args, "--force"], capsys)
    assert code == OK, err
    assert out.read_text().startswith("format: rfsas-calibration")
    assert not list(tmp_path.glob("*.part"))  # written beside, then renamed


def _scenario(
    tmp_path: Path, sensor_id: str = "rsu-nw", cal: str = "calibration/rsu-nw.yaml"
) -> Path:
    text = (REPO / "examples" / "crossing.yaml").read_text()
    text = text.replace("id: rsu-nw", f"id: {sensor_id!r}").replace(
        "calibration: calibration/rsu-nw.yaml", f"calibration: {cal}"
    )
    path = tmp_path / "scene.yaml"
    path.write_text(text)
    return path


def test_sim_turntable_never_overwrites_without_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scene = _scenario(tmp_path, cal="scene.yaml")  # the scenario names itself
    before = scene.read_text()
    code, _, err = run(["sim", "turntable", str(scene), "--force"], capsys)
    assert code == BAD_INPUT and "is also an input" in err
    assert scene.read_text() == before
    scene = _scenario(tmp_path)
    existing = tmp_path / "calibration" / "rsu-nw.yaml"
    existing.parent.mkdir()
    existing.write_text("measured on the real turntable\n")
    code, _, err = run(["sim", "turntable", str(scene), "--sensor", "rsu-nw"], capsys)
    assert code == BAD_INPUT and "--force" in err
    assert existing.read_text() == "measured on the real turntable\n"
    # a table named outside the scenario's directory is never written
    scene = _scenario(tmp_path, cal="../victim.yaml")
    code, _, err = run(["sim", "turntable", str(scene), "--sensor", "rsu-nw", "--force"], capsys)
    assert code == BAD_INPUT and "outside" in err
    assert not (tmp_path.parent / "victim.yaml").exists()


@pytest.mark.parametrize("bad_id", ["../../victim", "/etc/passwd", ".hidden", "a/b", "-rf", ""])
def test_sensor_ids_that_would_escape_the_output_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], bad_id: str
) -> None:
    scene = _scenario(tmp_path, sensor_id=bad_id)
    code, _, err = run(["sim", "capture", str(scene), "-o", str(tmp_path / "out")], capsys)
    assert code == BAD_INPUT, err
    assert "cannot be used in a file name" in err and "sensors[0].id" in err
    assert not (tmp_path / "victim.pcap").exists() and not (tmp_path / "out").exists()


def test_sim_capture_refuses_existing_captures_without_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scene = _scenario(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / "truth.jsonl").write_text("keep\n")
    code, _, err = run(["sim", "capture", str(scene), "-o", str(out)], capsys)
    assert code == BAD_INPUT and "--force" in err
    assert (out / "truth.jsonl").read_text() == "keep\n"


def test_board_emulate_never_replaces_a_users_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    notes = tmp_path / "notes.txt"
    notes.write_text("important\n")
    code, _, err = run(["board", "emulate", "--link", str(notes), "--duration", "0"], capsys)
    assert code == BAD_INPUT and "not a pseudo-terminal link" in err
    assert notes.read_text() == "important\n"
    stale = tmp_path / "ttyBOARD"
    stale.symlink_to("/dev/pts/999")  # what a killed emulator leaves behind
    code, out, err = run(["board", "emulate", "--link", str(stale), "--duration", "0"], capsys)
    assert code == OK, err
    assert out.strip() == str(stale)


@pytest.mark.parametrize("port", ["-5", "70000"])
def test_out_of_range_ports_are_usage_errors(port: str, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(["board", "emulate", "--tcp", port, "--duration", "0"], capsys)
    assert code == BAD_INPUT and "Traceback" not in err


def test_output_path_helpers() -> None:
    assert safe_name("rsu-nw.2") == "rsu-nw.2"
    for bad in ("..", "../x", "a/b", ".x", "", "x" * 65, "a\x00b"):
        with pytest.raises(Exception, match="file name"):
            safe_name(bad)
    with pytest.raises(Exception, match="outside"):
        inside("/tmp/out", "../victim")
    assert check_output("-", ["-"]) == Path("-")


@pytest.mark.parametrize("what", ["dir", "card"])
@pytest.mark.parametrize("mode", [0o777, 0o775, 0o757])
def test_a_trust_directory_others_can_write_is_refused(
    tmp_path: Path, what: str, mode: int
) -> None:
    backend = KeyStore.create(tmp_path / "obu", "backend")
    sensor = KeyStore.create(tmp_path / "rsu-1", "sensor")
    backend.trust.enroll(sensor.card)
    KeyStore.open(tmp_path / "obu")  # fine as made
    target = backend.trust.path if what == "dir" else backend.trust.path / "rsu-1.yaml"
    target.chmod(mode)
    with pytest.raises(KeyStoreError, match="other users change what is trusted"):
        KeyStore.open(tmp_path / "obu")


@pytest.mark.extra("sim")
def test_sim_commands_are_covered() -> None:
    """With the sim extra, the property test above also tries the sim commands."""
    assert {"sim evaluate --csv", "sim render"} <= {name for name, _, _ in COMMANDS}
