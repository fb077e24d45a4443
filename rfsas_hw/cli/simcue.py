"""``rfsas sim cueing``: how much sooner a cued vehicle has its own bearing (twin study)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from rfsas_hw.cli.options import json_option
from rfsas_hw.cli.outopts import OutputPath
from rfsas_hw.errors import ConfigError
from rfsas_hw.studies.cueing import PLANS, CueingConfig, Summary, brake_comparison, run_study


def _s(value: float) -> str:
    return "never" if math.isinf(value) else f"{value:.2f}"


def _table(summaries: list[Summary]) -> Table:
    table = Table(title="RSU first bearing → vehicle first bearing of the same emitter, seconds")
    for col in ("plan", "seeds", "mode", "median", "p90", "misses", "median ratio"):
        table.add_column(col, justify="left" if col in ("plan", "mode") else "right")
    for s in summaries:
        table.add_row(
            f"{s.channels} ch", str(s.trials), "hop plan",
            _s(s.uncued_median_s), _s(s.uncued_p90_s), str(s.uncued_misses), "",
        )  # fmt: skip
        table.add_row(
            "", "", "cued",
            _s(s.cued_median_s), _s(s.cued_p90_s), str(s.cued_misses), f"{s.speedup:.1f}×",
        )  # fmt: skip
    table.caption = "; ".join(
        f"{s.channels} ch: {s.fused}/{s.trials} first vehicle bearings fused with the cue's "
        f"bearing by keyed hash, median fix error {s.fused_median_error_m:.1f} m"
        for s in summaries
    )
    return table


@click.command("cueing")
@click.option("--seeds", type=int, default=100, show_default=True, help="Seeds per plan.")
@click.option("--first-seed", type=int, default=0, show_default=True, help="First seed.")
@click.option(
    "--plans",
    default="13,38",
    show_default=True,
    help="Vehicle hop plans to run: 13 (2.4 GHz) and/or 38 (2.4 + 5 GHz), comma-separated.",
)
@json_option("One JSON object instead of the table.")
@click.option(
    "--demo",
    "demo_dir",
    type=OutputPath("dir"),
    help="Instead: run the end-to-end demo with the vehicle sensor fixed, hopping 13 "
    "channels, and hopping cued (with and without the phone's probe sweeps); outputs here.",
)
def cueing(seeds: int, first_seed: int, plans: str, as_json: bool, demo_dir: Path | None) -> None:
    """Twin study: a roadside unit cues a hopping vehicle to the channel it heard a phone on.
    Time from the roadside unit's first bearing to the vehicle's first bearing of the
    same emitter (matched by keyed hash), with and without cueing, over SEEDS seeds."""
    if demo_dir is not None:
        _demo(demo_dir, as_json)
        return
    names = [p.strip() for p in plans.split(",") if p.strip()]
    unknown = [p for p in names if p not in PLANS]
    if unknown or not names:
        raise ConfigError(f"--plans: unknown plan(s) {unknown}; use {', '.join(PLANS)}")
    if seeds < 1:
        raise ConfigError("--seeds must be at least 1")
    console = Console(stderr=True)
    summaries, _ = run_study(
        range(first_seed, first_seed + seeds),
        names,
        CueingConfig(),
        progress=None if as_json else (lambda m: console.print(f"[dim]{m}[/]")),
    )
    if as_json:
        out = [
            {
                "plan_channels": s.channels,
                "seeds": s.trials,
                "no_rsu_bearing": s.no_rsu_bearing,
                "uncued": {
                    "median_s": s.uncued_median_s,
                    "p90_s": s.uncued_p90_s,
                    "misses": s.uncued_misses,
                },
                "cued": {
                    "median_s": s.cued_median_s,
                    "p90_s": s.cued_p90_s,
                    "misses": s.cued_misses,
                },
                "median_ratio": s.speedup,
                "fused": s.fused,
                "fused_median_error_m": s.fused_median_error_m,
            }
            for s in summaries
        ]
        click.echo(json.dumps(out, default=lambda v: None if math.isinf(v) else v))
        return
    Console().print(_table(summaries))


def _t(value: float | None) -> str:
    return "no BRAKE" if value is None else f"{value:.1f}"


def _demo(out_dir: Path, as_json: bool) -> None:
    console = Console(stderr=True)
    rows = []
    for probes in (True, False):
        r = brake_comparison(
            out_dir / ("with-probes" if probes else "data-only"),
            probes=probes,
            progress=None if as_json else (lambda m: console.print(f"[dim]{m}[/]")),
        )
        rows.append((probes, r))
    if as_json:
        click.echo(
            json.dumps(
                [
                    {
                        "phone_probes": p,
                        "first_brake_s": {
                            "fixed": r.fixed_s,
                            "hopping": r.hopping_s,
                            "cued": r.cued_s,
                        },
                        "brake_needed_by_s": r.needed_by_s,
                        "cues": r.cues,
                    }
                    for p, r in rows
                ]
            )
        )
        return
    table = Table(title="Demo: first BRAKE, scenario seconds")
    for col in ("phone sends", "vehicle fixed on ch 6", "hopping 13 ch", "hopping, cued"):
        table.add_column(col, justify="left" if col == "phone sends" else "right")
    for probes, r in rows:
        table.add_row(
            "data on 6 + probes on 1/6/11" if probes else "data on 6 only",
            _t(r.fixed_s), _t(r.hopping_s), _t(r.cued_s),
        )  # fmt: skip
    Console().print(table)
