"""``rfsas sumo run`` on the bundled crossing, the FCD → scenario → captures path, and no raw
MAC in anything a bridge run writes or prints."""

from __future__ import annotations

import base64
import json
import re
from pathlib import Path

import pytest
from click.testing import CliRunner

pytest.importorskip("libsumo", reason="needs the sumo extra: pip install 'rfsas-hw[sumo]'")

from rfsas_hw.bridges.fcd import fcd_to_scenario, read_fcd
from rfsas_hw.bridges.sumo_run import load_run_file
from rfsas_hw.cli.main import _load_commands, cli
from rfsas_hw.errors import ConfigError, DataFormatError, SimulationError
from rfsas_hw.twin.scenario import scenario_from_mapping
from rfsas_hw.twin.world import World

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "sumo"
_load_commands()


def _mac_forms(mac: str) -> list[re.Pattern[bytes]]:
    raw = bytes.fromhex(mac.replace(":", ""))
    pairs = [f"{b:02x}".encode() for b in raw]
    return [
        re.compile(rb"[^0-9a-fA-F]{0,3}".join(pairs), re.IGNORECASE),
        re.compile(re.escape(raw)),
        re.compile(re.escape(raw[::-1])),
        re.compile(rb"(?<![0-9])" + str(int.from_bytes(raw, "big")).encode() + rb"(?![0-9])"),
        re.compile(re.escape(base64.b64encode(raw))),
    ]


@pytest.fixture(scope="module")
def cli_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("sumo")
    result = CliRunner().invoke(
        cli,
        [
            "sumo",
            "run",
            "--seeds",
            "2",
            "--out",
            str(out / "run.jsonl"),
            "--truth",
            str(out / "truth.jsonl"),
            "--fcd",
            str(out / "fcd.xml"),
        ],
    )
    assert result.exit_code == 0, result.output
    return out, result.output


def test_bundled_crossing_runs_with_no_option(cli_run: tuple[Path, str]) -> None:
    out, printed = cli_run
    assert "2 seeds: 0 collisions" in printed
    lines = [json.loads(x) for x in (out / "run.jsonl").read_text().splitlines()]
    seeds = [x for x in lines if x["record"] == "seed"]
    assert [s["seed"] for s in seeds] == [0, 1]
    assert all(s["first_brake_s"] is not None and not s["collision"] for s in seeds)
    assert (out / "truth-seed0.jsonl").exists() and (out / "truth-seed1.jsonl").exists()


def test_no_raw_mac_in_any_output(cli_run: tuple[Path, str]) -> None:
    out, printed = cli_run
    macs = {
        json.loads(x)["mac"]
        for name in ("truth-seed0.jsonl", "truth-seed1.jsonl")
        for x in (out / name).read_text().splitlines()
        if json.loads(x)["record"] == "device"
    }
    assert len(macs) == 2
    # the truth file holds the MACs on purpose (scoring only); nothing else may
    outputs = {"run.jsonl": (out / "run.jsonl").read_bytes(), "stdout": printed.encode()}
    for mac in macs:
        for name, data in outputs.items():
            for pattern in _mac_forms(mac):
                assert not pattern.search(data), f"{mac} in {name} as {pattern.pattern!r}"


def test_fcd_to_scenario_to_captures(cli_run: tuple[Path, str], tmp_path: Path) -> None:
    out, _ = cli_run
    scenario = tmp_path / "scenario.yaml"
    result = CliRunner().invoke(
        cli,
        [
            "sumo",
            "fcd",
            str(out / "fcd.xml"),
            "--units",
            str(EXAMPLE / "units.yaml"),
            "--poly",
            str(EXAMPLE / "buildings.poly.xml"),
            "-o",
            str(scenario),
        ],
    )
    assert result.exit_code == 0, result.output
    caps = tmp_path / "caps"
    result = CliRunner().invoke(cli, ["sim", "capture", str(scenario), "-o", str(caps)])
    assert result.exit_code == 0, result.output
    assert (caps / "rsu-nw.pcap").stat().st_size > 1000
    cfg, _ = load_run_file(EXAMPLE / "units.yaml")
    tracks = read_fcd(out / "fcd.xml", cfg.origin_m)
    ped = tracks["person:ped"]
    data = fcd_to_scenario(out / "fcd.xml", cfg, ego="ego")
    world = World(scenario_from_mapping(data, "fcd"))
    # the scenario's pedestrian is where SUMO had it, sample by sample
    t0 = min(tr.t_s[0] for tr in tracks.values())
    for k in range(0, len(ped.t_s), 17):
        got = world.tracks["person:ped"].position([ped.t_s[k] - t0])[0]
        assert got == pytest.approx([ped.x_m[k], ped.y_m[k]], abs=1e-6)
    # the ego's box centre, 2.25 m behind the front bumper SUMO reports, in the lane
    ego = world.tracks["ego"].position([5.0])[0]
    assert ego[0] == pytest.approx(1.6, abs=1e-6)
    assert len(world.receptions("rsu-nw")) > 100


def test_fcd_errors(tmp_path: Path) -> None:
    cfg, _ = load_run_file(EXAMPLE / "units.yaml")
    bad = tmp_path / "bad.xml"
    bad.write_text("<fcd-export><timestep time='0'><vehicle id='a' x='1'/></timestep>")
    with pytest.raises(DataFormatError, match=r"not valid XML|no 'y'"):
        read_fcd(bad, (0.0, 0.0))
    empty = tmp_path / "empty.xml"
    empty.write_text("<fcd-export></fcd-export>")
    with pytest.raises(DataFormatError, match="no vehicle or person samples"):
        read_fcd(empty, (0.0, 0.0))
    one = tmp_path / "one.xml"
    one.write_text(
        "<fcd-export><timestep time='0'><vehicle id='a' x='1' y='2' angle='0'/>"
        "</timestep></fcd-export>"
    )
    with pytest.raises(SimulationError, match="no vehicle 'ego'"):
        fcd_to_scenario(one, cfg, ego="ego")


def test_missing_run_file_is_named(tmp_path: Path) -> None:
    lonely = tmp_path / "x.sumocfg"
    lonely.write_text("<configuration/>")
    result = CliRunner().invoke(cli, ["sumo", "run", str(lonely)])
    # main() turns the ConfigError into one line and exit code 2
    assert isinstance(result.exception, ConfigError) and "no run file" in str(result.exception)
