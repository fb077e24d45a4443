"""``sumo run --seeds`` on the project's runner: the same results with 0, 1 and 2 workers."""

from __future__ import annotations

import io
import json
from pathlib import Path

import pytest

pytest.importorskip("libsumo", reason="needs the sumo extra: pip install 'rfsas-hw[sumo]'")

from rfsas_hw.bridges.sumo_run import RunSummary, load_run_file, run_seeds
from rfsas_hw.errors import ConfigError

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "sumo"
SEEDS = [3, 1, 2]
TIMES = ("sumo_ms", "bridge_ms")
"""Wall-time fields: the only ones allowed to differ."""


def _run(workers: int) -> tuple[RunSummary, list[dict[str, object]], list[int]]:
    cfg, run = load_run_file(EXAMPLE / "units.yaml")
    sink = io.StringIO()
    order: list[int] = []
    summary = run_seeds(
        EXAMPLE / "crossing.sumocfg", cfg, run, SEEDS, controller="rfsas", out=sink,
        workers=workers, on_seed=lambda r: order.append(r.seed),
    )  # fmt: skip
    lines = [json.loads(x) for x in sink.getvalue().splitlines()]
    for x in lines:
        for k in TIMES:
            x.pop(k, None)
    return summary, lines, order


@pytest.mark.slow
def test_seeds_give_the_same_results_with_0_1_and_2_workers() -> None:
    pytest.importorskip("distributed", reason="needs the ncap extra: pip install 'rfsas-hw[ncap]'")
    here, here_lines, here_order = _run(0)
    one, one_lines, _ = _run(1)
    assert one.row() | dict.fromkeys(TIMES) == here.row() | dict.fromkeys(TIMES)
    two, two_lines, two_order = _run(2)
    assert here_order == two_order == SEEDS  # in the given order, whatever finished first
    assert [x["seed"] for x in two_lines if x["record"] == "seed"] == SEEDS
    assert any(x["record"] == "step" for x in two_lines)
    assert here_lines == one_lines == two_lines
    assert here.row() | dict.fromkeys(TIMES) == two.row() | dict.fromkeys(TIMES)
    # the seeds differ from each other, so equal results are not a constant
    assert len({json.dumps(x) for x in two_lines if x["record"] == "seed"}) == len(SEEDS)


def test_gui_and_repeated_seeds_are_refused_before_anything_runs() -> None:
    cfg, run = load_run_file(EXAMPLE / "units.yaml")
    crossing = EXAMPLE / "crossing.sumocfg"
    with pytest.raises(ConfigError, match="distinct"):
        run_seeds(crossing, cfg, run, [1, 1])
    with pytest.raises(ConfigError, match="in this process"):
        run_seeds(crossing, cfg, run, [1, 2], workers=2, gui=True)


def test_cli_refuses_gui_with_workers() -> None:
    from click.testing import CliRunner

    from rfsas_hw.cli.main import _load_commands, cli

    _load_commands()
    got = CliRunner().invoke(cli, ["sumo", "run", "--seeds", "2", "--gui", "--workers", "2"])
    assert isinstance(got.exception, ConfigError), got.output
    assert "--gui and --send run here" in str(got.exception)
