"""``rfsas ncap``: JSON lines, summary, grids, safe output paths, no raw MAC in any output."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

pytest.importorskip("libsumo", reason="needs the sumo extra (pip install .[sumo])")

from rfsas_hw.bridges.bridge import device_mac
from rfsas_hw.cli.main import _load_commands, cli
from rfsas_hw.errors import ConfigError
from rfsas_hw.ncap.rfsas import bridge_config
from rfsas_hw.records import int_to_mac
from tests.bridges.test_sumo_cli import _mac_forms

_load_commands()

ARGS = [
    "ncap", "--scenarios", "CPNCO,TN-KERB", "--speeds", "30", "--controllers", "los,rfsas+los",
    "--deployments", "car+rsu", "--devices", "phone-active", "--seeds", "1", "--workers", "0",
]  # fmt: skip


@pytest.fixture(scope="module")
def ran(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("ncap")
    res = CliRunner().invoke(cli, [*ARGS, "--out", str(out)])
    assert res.exit_code == 0, res.output
    return out, res.output


def test_one_line_per_run_a_summary_and_a_grid(ran: tuple[Path, str]) -> None:
    out, printed = ran
    lines = [json.loads(x) for x in (out / "runs.jsonl").read_text().splitlines()]
    # CPNCO has three impact locations, TN-KERB one; two configurations; one seed
    assert len(lines) == 8
    assert {x["config"] for x in lines} == {"los", "rfsas+los/car+rsu/phone-active"}
    assert all(x["record"] == "run" and x["seed"] == 0 for x in lines)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["runs"] == 8
    assert set(summary["points"]) == {"los", "rfsas+los/car+rsu/phone-active"}
    assert set(summary["nuisance"]["los"]) <= {0, 1}
    assert [g["config"] for g in summary["goals"]] == ["rfsas+los/car+rsu/phone-active"]
    assert (out / "CPNCO.png").read_bytes()[:4] == b"\x89PNG"
    assert not (out / "TN-KERB.png").exists()
    assert "Points per scenario" in printed and "CPNCO" in printed


def test_no_raw_mac_in_any_output(ran: tuple[Path, str]) -> None:
    out, printed = ran
    cfg = bridge_config("car+rsu", "phone-active", 0, ())
    macs = [int_to_mac(device_mac(cfg, f"person:{who}", 0)) for who in ("target", "walker")]
    blobs = [p.read_bytes() for p in out.iterdir()] + [printed.encode()]
    for mac in macs:
        for form in _mac_forms(mac):
            assert not any(form.search(b) for b in blobs), mac


def _error(args: list[str]) -> str:
    """The one line main() prints for a bad input (exit code 2)."""
    res = CliRunner().invoke(cli, args)
    assert isinstance(res.exception, ConfigError), res.output
    return str(res.exception)


def test_existing_outputs_are_kept_unless_forced(ran: tuple[Path, str]) -> None:
    out, _ = ran
    before = (out / "runs.jsonl").read_bytes()
    assert "exists; use --force" in _error([*ARGS, "--out", str(out)])
    assert (out / "runs.jsonl").read_bytes() == before


def test_the_second_roadside_unit_is_opt_in(tmp_path: Path) -> None:
    from rfsas_hw.cli.ncap import ncap

    default = next(p.default for p in ncap.params if p.name == "deployments")
    assert default == "car,car+rsu"  # the default matrix keeps one roadside unit
    res = CliRunner().invoke(cli, ["ncap", "--help"])
    assert res.exit_code == 0 and "car+2rsu" in res.output
    args = ["ncap", "--scenarios", "CBNAO", "--speeds", "30", "--controllers", "rfsas+los",
            "--deployments", "car+2rsu", "--devices", "phone-active", "--seeds", "1",
            "--workers", "0", "--no-plots", "--out", str(tmp_path)]  # fmt: skip
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 0, res.output
    (line,) = (tmp_path / "runs.jsonl").read_text().splitlines()
    assert json.loads(line)["config"] == "rfsas+los/car+2rsu/phone-active"
    # no raw MAC of the bicyclist (a SUMO vehicle: no person prefix) in any output either
    cfg = bridge_config("car+2rsu", "phone-active", 0, ())
    blobs = [p.read_bytes() for p in tmp_path.iterdir()] + [res.output.encode()]
    for who in ("target", "person:target"):
        mac = int_to_mac(device_mac(cfg, who, 0))
        for form in _mac_forms(mac):
            assert not any(form.search(b) for b in blobs), mac


def test_bad_choices_name_the_option(tmp_path: Path) -> None:
    out = ["--out", str(tmp_path)]
    assert "--scenarios: unknown scenario 'CPXX'" in _error(["ncap", "--scenarios", "CPXX", *out])
    assert "--speeds" in _error(["ncap", "--speeds", "fast", *out])
    assert "unknown device 'pager'" in _error(["ncap", "--devices", "pager", *out])
    cbla = _error(["ncap", "--scenarios", "CBLA", "--speeds", "10", *out])
    assert "speeds: 10 km/h: not a VUT speed of CBLA (CBLA tested at 20, 30, 40" in cbla
    assert "scenarios: none chosen" in _error(["ncap", "--scenarios", ",", *out])


def test_an_interrupted_sweep_writes_and_scores_the_runs_done(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from rfsas_hw.ncap.runner import run_one

    calls: list[object] = []

    def stopped_at_the_third(spec: object) -> object:
        calls.append(spec)
        if len(calls) == 3:
            raise KeyboardInterrupt  # what Ctrl-C, or SIGTERM through the CLI, raises
        return run_one(spec)  # type: ignore[arg-type]

    monkeypatch.setattr("rfsas_hw.ncap.sweep.run_one", stopped_at_the_third)
    args = ["ncap", "--scenarios", "CPNCO", "--speeds", "20", "--controllers", "los"]
    args += ["--seeds", "1", "--workers", "0", "--no-plots", "--out", str(tmp_path)]
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 130, res.output
    assert "after 2 of 3 runs" in res.output
    lines = [json.loads(x) for x in (tmp_path / "runs.jsonl").read_text().splitlines()]
    assert [x["cell"] for x in lines] == ["CPNCO-25@20", "CPNCO-50@20"]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["interrupted"] is True
    assert (summary["runs"], summary["runs_planned"]) == (2, 3)
    assert {c["cell"] for c in summary["cells"]} == {"CPNCO-25@20", "CPNCO-50@20"}
