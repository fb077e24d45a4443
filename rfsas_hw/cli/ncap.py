"""``rfsas ncap``: the Euro NCAP VRU test matrix in SUMO, with LOS AEB, RF-SAS and both."""

from __future__ import annotations

import json
from pathlib import Path

import click
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from rfsas_hw.cli.exitcodes import Interrupted
from rfsas_hw.cli.options import runner_options
from rfsas_hw.cli.outopts import OutputPath
from rfsas_hw.errors import ConfigError

DEFAULT_WORKERS = 2
"""Worker processes of the local cluster unless --workers says otherwise."""
ALL = "all"
TN = "tn"


def _split(value: str) -> list[str]:
    return [v.strip() for v in value.split(",") if v.strip()]


def _scenario_names(value: str) -> list[str]:
    from rfsas_hw.ncap.scenarios import SCENARIOS, TRUE_NEGATIVES

    names: list[str] = []
    for v in _split(value):
        if v == ALL:
            names += [*SCENARIOS, *TRUE_NEGATIVES]
        elif v == TN:
            names += list(TRUE_NEGATIVES)
        elif v in SCENARIOS or v in TRUE_NEGATIVES:
            names.append(v)
        else:
            known = ", ".join([ALL, TN, *SCENARIOS, *TRUE_NEGATIVES])
            raise ConfigError(f"--scenarios: unknown scenario {v!r} (known: {known})")
    return list(dict.fromkeys(names))


def _speeds(value: str | None) -> list[float] | None:
    if value is None:
        return None
    try:
        return [float(v) for v in _split(value)]
    except ValueError:
        raise ConfigError(
            f"--speeds: expected km/h numbers separated by commas, got {value!r}"
        ) from None


@click.command()
@click.option(
    "--scenarios",
    default=ALL,
    show_default=True,
    help="Comma-separated scenarios (CPNA, CPFA, CPNCO, CPLA, CBNA, CBNAO, CBFA, CBLA, CPTA, "
    "CBTA, "
    "TN-ALONG, TN-KERB, TN-BEHIND, TN-BIKELANE, TN-PHONES), 'tn' for the true "
    "negatives, 'all' for everything.",
)
@click.option(
    "--speeds",
    default=None,
    help="VUT speeds in km/h, comma-separated; a scenario skips the ones it does not test "
    "(default: each scenario's own, 10-60; CBLA 20-60, CPTA/CBTA 10-20).",
)
@click.option(
    "--controllers",
    default="los,rfsas,rfsas+los,los+cue",
    show_default=True,
    help="none, los, rfsas, rfsas+los, los+cue (comma-separated).",
)
@click.option(
    "--deployments",
    default="car,car+rsu",
    show_default=True,
    help="RF-SAS deployments: car (the VUT's unit only), car+rsu (and a roadside unit "
    "across the road), car+2rsu (and a second one on the nearside kerb; opt-in).",
)
@click.option(
    "--devices",
    default="phone-active,phone-idle",
    show_default=True,
    help="Device models the targets carry: phone-active (data bursts every 0.1 s), "
    "phone-idle (probe bursts every 5 s).",
)
@click.option(
    "--seeds", default=3, show_default=True, type=click.IntRange(1), help="Seeds per cell."
)
@click.option(
    "--first-seed",
    default=0,
    show_default=True,
    type=click.IntRange(0),
    help="Seeds are FIRST-SEED … FIRST-SEED + SEEDS - 1 (to add seeds to an earlier sweep).",
)
@runner_options(default_workers=DEFAULT_WORKERS, what="runs")
@click.option(
    "--out",
    "out_dir",
    required=True,
    type=OutputPath("dir"),
    help="Directory for runs.jsonl, summary.json and one PNG per scenario.",
)
@click.option("--no-plots", is_flag=True, help="Do not draw the grids.")
@click.option("--force", is_flag=True, help="Replace existing output files.")
def ncap(
    scenarios: str, speeds: str | None, controllers: str, deployments: str, devices: str,
    seeds: int, first_seed: int, workers: int, scheduler: str | None, out_dir: Path,
    no_plots: bool, force: bool,
) -> None:  # fmt: skip
    """Run part of the Euro NCAP VRU matrix in SUMO and score it like the protocol.

    A simulation of RF-SAS's potential on the protocol's geometry, not a Euro NCAP rating.
    Ctrl-C or SIGTERM stops the sweep: the runs done by then are written and scored
    (``interrupted`` in the summary) and the exit code is 130.
    """
    from rfsas_hw.ncap.runner import RunResult
    from rfsas_hw.ncap.scenarios import cells
    from rfsas_hw.ncap.scoring import goal_configs, goals, nuisance, points, score_cells
    from rfsas_hw.ncap.sweep import configs, run_sweep, specs_for
    from rfsas_hw.outpaths import AtomicFile, check_output, inside, safe_name, write_text_atomic

    names = _scenario_names(scenarios)
    chosen = cells(names, _speeds(speeds))
    conf = configs(_split(controllers), _split(deployments), _split(devices))
    specs = specs_for(chosen, conf, list(range(first_seed, first_seed + seeds)))
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ConfigError(f"--out {out_dir}: cannot create: {err.strerror or err}") from err
    runs_path = check_output(inside(out_dir, "runs.jsonl"), force=force)
    summary_path = check_output(inside(out_dir, "summary.json"), force=force)
    pngs = {}
    if not no_plots:
        for name in dict.fromkeys(c.scenario for c in chosen):
            if not name.startswith("TN-"):
                png = inside(out_dir, f"{safe_name(name, 'scenario')}.png")
                pngs[name] = check_output(png, force=force)
    console = Console(stderr=True)
    columns = (
        TextColumn("ncap"), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[last]}"),
        TimeElapsedColumn(),
    )  # fmt: skip
    got: dict[int, RunResult] = {}
    interrupted = False
    try:
        with Progress(*columns, console=console) as bar:
            task = bar.add_task("runs", total=len(specs), last="")

            def done(i: int, r: RunResult) -> None:
                got[i] = r
                bar.update(task, advance=1, last=specs[i].cell.key)

            run_sweep(specs, workers=workers, scheduler=scheduler, on_result=done)
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: the runs done are still written
        interrupted = True
    results = [got[i] for i in sorted(got)]
    # a failed write ends the command through the shared output rules (exit 1)
    with AtomicFile(runs_path, newline=None) as sink:
        for r in results:
            sink.stream.write(json.dumps({"record": "run", **r.as_dict()}) + "\n")
    scored = score_cells(results)
    pts = points(scored)
    nuis = nuisance(results)
    summary = {
        "runs": len(results),
        "runs_planned": len(specs),
        "interrupted": interrupted,
        "cells": [c.as_dict() for c in scored],
        "points": {k: {s: list(v) for s, v in d.items()} for k, d in pts.items()},
        "nuisance": {k: list(v) for k, v in nuis.items()},
        "goals": [
            goals(scored, pts, nuis, config) for config in goal_configs(r.config for r in results)
        ],
        "wall_s_total": sum(r.wall_s for r in results),
        "cpu_s_total": sum(r.cpu_s for r in results),
    }
    write_text_atomic(summary_path, json.dumps(summary, indent=1) + "\n")
    if pngs:
        from rfsas_hw.ncap.grid_plot import plot_scenario

        for name, png in pngs.items():
            plot_scenario(name, scored, pts, png)
    _print_table(pts, nuis)
    Console().print(f"{len(results)} runs → {runs_path}, {summary_path}"
                    + (f", {len(pngs)} grids" if pngs else ""))  # fmt: skip
    if interrupted:
        raise Interrupted(
            f"after {len(results)} of {len(specs)} runs (those runs are written and scored)"
        )


def _print_table(
    pts: dict[str, dict[str, tuple[float, float]]], nuis: dict[str, tuple[int, int]]
) -> None:
    scen = sorted({s for d in pts.values() for s in d})
    table = Table(title="Points per scenario (earned / available) and nuisance brakes")
    table.add_column("configuration")
    for s in scen:
        table.add_column(s, justify="right")
    table.add_column("total", justify="right")
    table.add_column("nuisance", justify="right")
    for config in sorted({*pts, *nuis}, key=lambda c: (c.count("/"), c)):
        d = pts.get(config, {})
        got = sum(v[0] for v in d.values())
        full = sum(v[1] for v in d.values())
        n = nuis.get(config)
        table.add_row(
            config,
            *[f"{d[s][0]:.2f}/{d[s][1]:g}" if s in d else "—" for s in scen],
            f"{got:.2f}/{full:g}" if d else "—",
            f"{n[0]}/{n[1]}" if n else "—",
        )
    Console().print(table)
