"""The ``rfsas sim``, ``rfsas plan`` (and ``rfsas demo``) commands."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from rfsas_hw.cli.main import _load_commands, cli
from rfsas_hw.twin.capture_writer import read_truth

from .conftest import EXAMPLE


@pytest.fixture(scope="module")
def runner() -> CliRunner:
    _load_commands()
    return CliRunner()


def test_sim_capture_writes_files_and_truth(runner: CliRunner, tmp_path: Path) -> None:
    res = runner.invoke(cli, ["sim", "capture", str(EXAMPLE), "-o", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "rsu-nw.pcap").stat().st_size > 1000
    assert (tmp_path / "car-obu.pcap").stat().st_size > 1000
    truth = read_truth(tmp_path / "truth.jsonl")
    assert set(truth.tracks) == {"pedestrian", "car"}
    assert "rsu-nw" in res.output and "frames" in res.output


def test_plan_json(runner: CliRunner) -> None:
    res = runner.invoke(
        cli,
        [
            "plan",
            "--channels",
            "1,6,11",
            "--dwell",
            "100",
            "--receivers",
            "1",
            "--emitter",
            "beacon",
            "--trials",
            "300",
            "--json",
        ],
    )
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    assert out["revisit_s"] == pytest.approx(0.3)
    assert 0 < out["mean_s"] < out["p90_s"] < 1.0


def test_plan_rejects_bad_channels(runner: CliRunner) -> None:
    res = runner.invoke(cli, ["plan", "--channels", "one,six"])
    assert res.exit_code != 0
    assert "--channels" in str(res.exception) or "--channels" in res.output


def test_sim_capture_every_receiver_type(runner: CliRunner, tmp_path: Path) -> None:
    from rfsas_hw.records import ObservationBatch
    from rfsas_hw.sources import open_source

    scenario = EXAMPLE.parent / "receivers.yaml"
    res = runner.invoke(
        cli, ["sim", "capture", str(scenario), "-o", str(tmp_path), "--format", "pcapng"]
    )
    assert res.exit_code == 0, res.output
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == [
        "board.board.bin",
        "hopper.pcapng",
        "pair-card0.pcapng",
        "pair-card1.pcapng",
        "truth.jsonl",
    ]
    with open_source(f"pcap:{tmp_path / 'hopper.pcapng'}") as src:
        hop = ObservationBatch.concat(list(src))
    assert set(hop.channel.tolist()) == {1, 6, 11}
    pair = f"pcap:{tmp_path / 'pair-card0.pcapng'}+{tmp_path / 'pair-card1.pcapng'}"
    with open_source(pair) as src:
        paired = ObservationBatch.concat(list(src))
        assert src.stats.as_dict()["pairing_rate"] > 0.9
    assert len(paired) > 20
