"""``rfsas city run`` as a command: the off run on a small grid writes its run log, summary
and map, prints the table; bad input is refused with the option named."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from rfsas_hw.cli.city import city

pytest.importorskip("libsumo", reason="needs the city extra: pip install 'rfsas-hw[city]'")


def test_off_run_writes_log_summary_and_map(grid_net: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    args = ["run", "--net", str(grid_net), "--out", str(out), "--duration", "20"]
    args += ["--vehicles", "20", "--pedestrians", "30", "--bicycles", "5", "--rfsas", "off"]
    res = CliRunner().invoke(city, [*args, "--no-png"])
    assert res.exit_code == 0, res.output
    assert "conflicts" in res.output
    summary = json.loads((out / "off.summary.json").read_text())
    assert summary["summary"]["steps"] == 200
    assert summary["runtime"]["realtime_factor"] > 0
    records = [json.loads(ln) for ln in (out / "off.log.jsonl").read_text().splitlines()]
    assert records[0]["record"] == "start" and records[-1]["record"] == "end"
    assert sum(r["record"] == "second" for r in records) == 20
    geo = json.loads((out / "off.map.geojson").read_text())
    assert geo["type"] == "FeatureCollection"


def test_bad_options_are_refused(grid_net: Path, tmp_path: Path) -> None:
    runner = CliRunner()
    res = runner.invoke(city, ["run", "--out", str(tmp_path), "--duration", "0"])
    assert res.exit_code == 2 and "--duration" in res.output
    res = runner.invoke(city, ["run", "--out", str(tmp_path), "--net", "missing.net.xml"])
    assert res.exit_code == 2 and "--net" in res.output
    res = runner.invoke(city, ["run", "--out", str(tmp_path), "--deployment-nice", "20"])
    assert res.exit_code == 2 and "--deployment-nice" in res.output


def test_an_earlier_runs_files_are_replaced_only_with_force(grid_net: Path, tmp_path: Path) -> None:
    from rfsas_hw.errors import ConfigError

    out = tmp_path / "out"
    out.mkdir()
    (out / "on.map.geojson").write_text("keep\n")
    args = ["run", "--net", str(grid_net), "--out", str(out), "--duration", "5", "--no-png"]
    res = CliRunner().invoke(city, args)
    assert isinstance(res.exception, ConfigError)
    assert "on.map.geojson exists; use --force" in str(res.exception)
    assert sorted(p.name for p in out.iterdir()) == ["on.map.geojson"]  # nothing ran
    assert (out / "on.map.geojson").read_text() == "keep\n"
    # the off run alone does not touch the on run's files
    res = CliRunner().invoke(city, [*args, "--rfsas", "off", "--vehicles", "0", "--bicycles", "0",
                                    "--pedestrians", "3"])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert (out / "on.map.geojson").read_text() == "keep\n"
