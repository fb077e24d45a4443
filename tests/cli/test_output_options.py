"""Every output option of every command keeps the same promises.

The commands are found by walking the ``rfsas`` command tree, so a new command
with an output option fails here until it has an invocation below: its output
never replaces one of its inputs, an existing file only with ``--force`` (a
secret, a key card or a new directory never), and a write that fails (``/dev/full``)
ends with one clear line and a non-zero exit code, never a traceback or a 0.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import click
import pytest
from clihelp import REPO, STILL, run, write_calibration, write_capture

from rfsas_hw.cli import main as cli_main
from rfsas_hw.cli.exitcodes import BAD_INPUT, FAILED
from rfsas_hw.cli.outopts import OutputPath
from rfsas_hw.link.keys import KeyStore


def _walk(command: click.Command, path: tuple[str, ...]) -> list[tuple[str, click.Parameter]]:
    if isinstance(command, click.Group):
        return [
            found
            for name, sub in sorted(command.commands.items())
            for found in _walk(sub, (*path, name))
        ]
    return [(" ".join(path), p) for p in command.params]


def _all_params() -> list[tuple[str, click.Parameter]]:
    cli_main._load_commands()
    return _walk(cli_main.cli, ())


def _long(param: click.Parameter) -> str:
    """The option's longest name shown in ``--help`` (not an old name kept as an alias)."""
    hidden = getattr(param, "hidden_aliases", ())
    return max((o for o in param.opts if o not in hidden), key=len)


def output_options() -> list[tuple[str, str, str]]:
    """(command, option, kind) of every output option."""
    return [
        (cmd, _long(p), p.type.kind) for cmd, p in _all_params() if isinstance(p.type, OutputPath)
    ]


WRITE_NAMES = ("out", "output", "plot", "csv", "fcd", "truth", "logs", "rosbag2", "prior", "demo")
"""Option names that say a path is written."""

NOT_OUTPUTS = {
    ("board emulate", "--link"): "a symlink to the emulator's pty, with its own never-a-file rule",
    ("aoa emulate ublox", "--link"): "a symlink to the emulator's pty, with its own rule",
}


def test_every_path_option_that_writes_is_an_output_option() -> None:
    unmarked = [
        (cmd, _long(p))
        for cmd, p in _all_params()
        if isinstance(p.type, click.Path)
        and not isinstance(p.type, OutputPath)
        and any(name in _long(p).lstrip("-").split("-") for name in WRITE_NAMES)
        and (cmd, _long(p)) not in NOT_OUTPUTS
    ]
    assert unmarked == []
    assert len(output_options()) >= 25


def test_every_command_with_a_replaceable_output_has_force() -> None:
    for cmd, p in _all_params():
        if isinstance(p.type, OutputPath) and p.type.kind in ("file", "file_or_new_dir"):
            names = {q.name for c, q in _all_params() if c == cmd}
            assert "force" in names, cmd


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("outputs")
    write_capture(d / "cap.pcap", n=60, span_s=6.0)
    write_calibration(d / "cal.yaml")
    shutil.copy(REPO / "calibration" / "example_turntable.csv", d / "sweep.csv")
    shutil.copytree(REPO / "examples" / "sumo", d / "sumo")
    shutil.copy(REPO / "examples" / "crossing.yaml", d / "scene.yaml")
    (d / "env.yaml").write_text("{}\n")
    lines = [
        '{"record": "site", "origin": {"lat_deg": 52.2, "lon_deg": 0.12, "height_m": 0}}',
        '{"record": "fix", "t_ns": 1000000000, "emitter": "00000000000000aa", "x_m": 5.0, '
        '"y_m": 7.0, "covariance": [[1, 0], [0, 1]], "ok": true, "sensors": ["a", "b"]}',
    ]
    (d / "run.jsonl").write_text("\n".join(lines) + "\n")
    auth = KeyStore.create(d / "keys" / "auth", "authority")
    sensor = KeyStore.create(d / "keys" / "rsu-1", "sensor")
    obu = KeyStore.create(d / "keys" / "obu", "backend")
    auth.trust.enroll(sensor.card)
    auth.trust.enroll(obu.card)
    obu.trust.enroll(sensor.card)
    try:  # SUMO's FCD output, the input of ``sumo fcd``
        cli_main.main(["sumo", "run", str(d / "sumo" / "crossing.sumocfg"), "--fcd",
                       str(d / "sumo" / "fcd.xml")])  # fmt: skip
    except SystemExit as exc:
        assert exc.code in (0, None)
    # a small signalised grid, the input of ``city run``
    from rfsas_hw.city.net import sumo_binary, sumo_env

    netgen = [str(sumo_binary("netgenerate")), "--grid", "--grid.number=2", "--sidewalks.guess"]
    netgen += ["--default.junctions.type=traffic_light", "-o", str(d / "grid.net.xml")]
    subprocess.run(netgen, env=sumo_env(), check=True, capture_output=True, timeout=60)
    return d


BACKEND = ["backend", "--listen", "udp://127.0.0.1:0", "--keys", "keys/obu", "--no-table"]
BACKEND_RUN = [*BACKEND, "--duration", "0.3", "--map", "scene.yaml"]
SUMO = ["sumo", "run", "sumo/crossing.sumocfg"]
SUMO_INPUTS = ["sumo/crossing.sumocfg", "sumo/units.yaml", "sumo/crossing.net.xml"]

# command, option -> (arguments with {out}, the inputs it reads)
INVOCATIONS: dict[tuple[str, str], tuple[list[str], list[str]]] = {
    ("aoa emulate bleiq", "--out"): (["aoa", "emulate", "bleiq", "--packets", "5", "-o", "{out}"],
                                     []),
    ("aoa emulate bleiq", "--calibration-out"): (["aoa", "emulate", "bleiq", "--packets", "5",
                                                  "-o", "iq.btsnoop", "--calibration-out",
                                                  "{out}"], []),
    ("city run", "--out"): (["city", "run", "--net", "grid.net.xml", "--origin", "52.43,13.53",
                             "--duration", "2", "--vehicles", "2", "--pedestrians", "2",
                             "--bicycles", "1", "--rfsas", "off", "--no-png", "--out", "{out}"],
                            ["grid.net.xml"]),
    ("city run", "--work"): (["city", "run", "--net", "grid.net.xml", "--origin", "52.43,13.53",
                              "--duration", "2", "--vehicles", "2", "--pedestrians", "2",
                              "--bicycles", "1", "--rfsas", "off", "--no-png", "--out", "city",
                              "--work", "{out}"], ["grid.net.xml"]),
    ("city keys", "--out"): (["city", "keys", "--net", "grid.net.xml", "--origin", "52.43,13.53",
                              "--out", "{out}"], ["grid.net.xml"]),
    ("ncap", "--out"): (["ncap", "--scenarios", "CPNA", "--speeds", "20", "--controllers",
                         "los", "--deployments", "car", "--devices", "phone-active", "--seeds",
                         "1", "--workers", "0", "--no-plots", "--out", "{out}"], []),
    ("backend", "--out"): ([*BACKEND_RUN, "--out", "{out}"],
                           ["scene.yaml", "keys/obu/identity.yaml"]),
    ("backend", "--plot"): ([*BACKEND_RUN, "--plot", "{out}"], ["scene.yaml"]),
    ("backend", "--prior"): ([*BACKEND_RUN, "--prior", "{out}"], ["scene.yaml"]),
    ("backend", "--rosbag2"): ([*BACKEND_RUN, "--rosbag2", "{out}"], ["scene.yaml"]),
    ("broker config", "--out"): (["broker", "config", "--keys", "keys/auth", "--out", "{out}"],
                                 ["keys/auth/identity.yaml"]),
    ("calibrate", "--out"): (["calibrate", "sweep.csv", "-o", "{out}"], ["sweep.csv"]),
    ("calibrate", "--plot"): (["calibrate", "sweep.csv", "-o", "/dev/null", "--plot", "{out}"],
                              ["sweep.csv"]),
    ("demo", "--out"): (["demo", "--scenario", "scene.yaml", "-o", "{out}"], ["scene.yaml"]),
    ("export", "--out"): (["export", "run.jsonl", "--to", "kml", "-o", "{out}"], ["run.jsonl"]),
    ("keys export", "--out"): (["keys", "export", "keys/rsu-1", "-o", "{out}"],
                                  ["keys/rsu-1/identity.yaml"]),
    ("keys new", "--out"): (["keys", "new", "--role", "sensor", "-o", "{out}"], []),
    ("live", "--out"): (["live", "pcap:cap.pcap", "--calibration", "cal.yaml", "--out", "{out}",
                         "--format", "csv", *STILL], ["cap.pcap", "cal.yaml"]),
    ("nonces secret", "--out"): (["nonces", "secret", "-o", "{out}"], []),
    ("replay", "--out"): (["replay", "cap.pcap", "--calibration", "cal.yaml", "--out", "{out}",
                           "--format", "jsonl", *STILL], ["cap.pcap", "cal.yaml"]),
    ("sim braking", "--plot"): (["sim", "braking", "--plot", "{out}"], []),
    ("sim capture", "--out"): (["sim", "capture", "scene.yaml", "-o", "{out}"], ["scene.yaml"]),
    ("sim cueing", "--demo"): (["sim", "cueing", "--demo", "{out}"], []),
    ("sim evaluate", "--csv"): (["sim", "evaluate", "--model", "model.zip", "--episodes", "1",
                                 "--distances", "60", "--csv", "{out}"], ["model.zip"]),
    ("sim evaluate", "--plot"): (["sim", "evaluate", "--model", "model.zip", "--episodes", "1",
                                  "--distances", "60", "--plot", "{out}"], ["model.zip"]),
    ("sim render", "--out"): (["sim", "render", "--config", "env.yaml", "-o", "{out}"],
                                 ["env.yaml"]),
    ("sim train", "--logs"): (["sim", "train", "--config", "env.yaml", "-o", "m.zip",
                               "--logs", "{out}"], ["env.yaml"]),
    ("sim train", "--out"): (["sim", "train", "--config", "env.yaml", "-o", "{out}"],
                                ["env.yaml"]),
    ("sumo fcd", "--out"): (["sumo", "fcd", "sumo/fcd.xml", "--units", "sumo/units.yaml", "-o",
                                "{out}"], ["sumo/fcd.xml", "sumo/units.yaml"]),
    ("sumo run", "--fcd"): ([*SUMO, "--fcd", "{out}"], SUMO_INPUTS),
    ("sumo run", "--out"): ([*SUMO, "--out", "{out}"], SUMO_INPUTS),
    ("sumo run", "--truth"): ([*SUMO, "--truth", "{out}"], SUMO_INPUTS),
}  # fmt: skip

FULL_AS = {("sim render", "--out"): "full.gif"}
"""A name for /dev/full where the command takes its format from the suffix."""

SLOW_ON_DEV_FULL = {
    ("sim train", "--out"),
    ("sim evaluate", "--csv"),
    ("sim evaluate", "--plot"),
}
"""Outputs written only after minutes of work (training, evaluation)."""


def test_every_output_option_has_an_invocation() -> None:
    found = {(cmd, opt) for cmd, opt, _ in output_options()}
    assert found == set(INVOCATIONS)


def _cases() -> list[tuple[str, str, str]]:
    return output_options()


def _args(cmd: str, opt: str, out: str) -> list[str]:
    args, _ = INVOCATIONS[(cmd, opt)]
    return [out if a == "{out}" else a for a in args]


def _snapshot(d: Path, names: list[str]) -> dict[str, bytes]:
    return {n: (d / n).read_bytes() for n in names}


@pytest.mark.parametrize(("cmd", "opt", "kind"), _cases())
def test_an_output_never_replaces_an_input(
    workdir: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    cmd: str,
    opt: str,
    kind: str,
) -> None:
    monkeypatch.chdir(workdir)
    _, inputs = INVOCATIONS[(cmd, opt)]
    if not inputs:
        pytest.skip(f"{cmd} reads no file")
    if cmd == "sim evaluate":
        (workdir / "model.zip").write_bytes(b"PK\x05\x06" + bytes(18))
    for victim in inputs:
        before = _snapshot(workdir, inputs)
        force = ["--force"] if kind in ("file", "file_or_new_dir") else []
        code, _, err = run([*_args(cmd, opt, victim), *force], capsys)
        assert code == BAD_INPUT, (victim, err)
        assert "Traceback" not in err
        assert "also an input" in err or "is a file" in err or "exists" in err, err
        assert _snapshot(workdir, inputs) == before


@pytest.mark.parametrize(("cmd", "opt", "kind"), _cases())
def test_an_existing_output_is_replaced_only_with_force(
    tmp_path: Path,
    workdir: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    cmd: str,
    opt: str,
    kind: str,
) -> None:
    monkeypatch.chdir(workdir)
    if cmd == "sim evaluate":
        (workdir / "model.zip").write_bytes(b"PK\x05\x06" + bytes(18))
    existing = tmp_path / "existing.out"
    existing.write_text("keep\n")
    if kind == "update":
        pytest.skip("read and written back: an existing file is its purpose")
    code, _, err = run(_args(cmd, opt, str(existing)), capsys)
    assert code == BAD_INPUT, err
    assert "Traceback" not in err and existing.name in err
    assert existing.read_text() == "keep\n"
    if kind == "file":
        assert "--force" in err
    if kind in ("new_dir", "file_or_new_dir"):
        folder = tmp_path / "existing-dir"
        folder.mkdir()
        (folder / "keep.txt").write_text("keep\n")
        force = ["--force"] if kind == "file_or_new_dir" else []
        code, _, err = run([*_args(cmd, opt, str(folder)), *force], capsys)
        assert code == BAD_INPUT and "Traceback" not in err, err
        assert (folder / "keep.txt").read_text() == "keep\n"


@pytest.mark.parametrize(("cmd", "opt", "kind"), _cases())
def test_a_full_disk_ends_with_one_clear_line(
    workdir: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    cmd: str,
    opt: str,
    kind: str,
) -> None:
    if (cmd, opt) in SLOW_ON_DEV_FULL:
        pytest.skip("written after minutes of training; AtomicFile/OutputError cover it")
    monkeypatch.chdir(workdir)
    full = FULL_AS.get((cmd, opt), "/dev/full")
    if full != "/dev/full" and not (workdir / full).is_symlink():
        (workdir / full).symlink_to("/dev/full")
    code, out, err = run(_args(cmd, opt, full), capsys)
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1] if err.strip() else ""
    if kind in ("dir", "new_dir", "new_file", "update"):
        # a device is not a directory, a file that must be new exists, and a file
        # read back is not a device
        assert code == BAD_INPUT and last.startswith("error:"), err
    elif code == FAILED:
        assert last.startswith("failed:") and "No space left on device" in last, err
    else:
        # a target SUMO writes itself is refused when it is not a regular file
        assert code == BAD_INPUT and cmd == "sumo run" and "/dev/full" in last, err
    assert f"wrote {full}" not in out


def test_every_output_is_checked_before_any_is_opened(
    workdir: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.chdir(workdir)
    recording = tmp_path / "run.mcap"
    recording.write_bytes(b"an earlier recording")
    bag = tmp_path / "bag"
    bag.mkdir()
    args = [*BACKEND_RUN, "--out", str(recording), "--rosbag2", str(bag), "--force"]
    code, _, err = run(args, capsys)
    assert code == BAD_INPUT and "Traceback" not in err, err
    assert recording.read_bytes() == b"an earlier recording"  # not emptied by a later refusal
    same = [*BACKEND_RUN, "--out", str(recording), "--plot", str(recording), "--force"]
    code, _, err = run(same, capsys)
    assert code == BAD_INPUT and "is also --out" in err
