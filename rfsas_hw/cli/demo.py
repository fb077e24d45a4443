"""``rfsas demo`` (= ``make demo``): the bundled scenario end to end, with a table and a map."""

from __future__ import annotations

import math
from pathlib import Path

import click
import numpy as np
from rich import box
from rich.console import Console
from rich.table import Table

from rfsas_hw.cli.options import out_option
from rfsas_hw.studies.demo import DemoResult, run_demo


def _f(value: float, digits: int = 2, unit: str = "") -> str:
    return "—" if not math.isfinite(value) else f"{value:.{digits}f}{unit}"


def _table(result: DemoResult, every_s: float) -> Table:
    table = Table(
        title="Pedestrian fixes (RSU + car, signed UDP); * = flagged fix, ◀ = decided BRAKE",
        box=box.SIMPLE_HEAD,
        padding=(0, 1),
    )
    for col in (
        "t s",
        "truth m",
        "fix m",
        "err m",
        "1σ m",
        "err/σ",
        "P_coll",
        "risk",
        "advice",
        "car m",
    ):
        table.add_column(col, justify="right")
    decisive = result.decisive
    last_t = -math.inf
    for r in result.rows:
        if r.fix is None or not r.fix_new:
            continue
        marked = decisive is not None and r is decisive
        if r.t_s - last_t < every_s - 1e-9 and not marked:
            continue
        last_t = r.t_s
        a = r.assessment
        gap = float(np.hypot(*(r.truth_xy - r.vehicle_xy)))
        table.add_row(
            f"{r.t_s:.1f}" + ("◀" if marked else ""),
            f"{r.truth_xy[0]:.1f},{r.truth_xy[1]:.1f}",
            f"{r.fix.x_m:.1f},{r.fix.y_m:.1f}" + ("" if r.fix.ok else "*"),
            _f(r.error_m, 1),
            _f(r.sigma_major_m, 1),
            _f(r.mahalanobis, 2),
            _f(a.p_collision, 3) if a is not None else "—",
            _f(a.risk, 4) if a is not None else "—",
            a.advisory if a is not None else "—",
            f"{gap:.0f}",
        )
    return table


@click.command()
@click.option(
    "--scenario",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Scenario file (default: the bundled examples/crossing.yaml).",
)
@out_option(
    "Where the outputs go.",
    dest="out_dir",
    kind="dir",
    default=Path("out/demo"),
)
@click.option(
    "--reaction",
    "reaction_s",
    type=float,
    default=0.5,
    show_default=True,
    help="Reaction delay the advisory allows for, s.",
)
@click.option(
    "--every",
    "every_s",
    type=float,
    default=0.5,
    show_default=True,
    help="Table row spacing, s of scenario time.",
)
@click.option("--no-plot", is_flag=True, help="Skip the map PNG.")
@click.option(
    "--cpm",
    "cpm_url",
    metavar="URL",
    help="Also send the backend's tracks as ETSI CPMs: udp://HOST:PORT[?btp=1] or "
    "mqtt://HOST[:PORT]/TOPIC (docs/v2x.md).",
)
@click.option(
    "--cpm-station-id",
    type=click.IntRange(0, 2**32 - 1),
    default=1,
    show_default=True,
    help="StationId of the demo's roadside unit in its CPMs.",
)
def demo(
    scenario: Path | None,
    out_dir: Path,
    reaction_s: float,
    every_s: float,
    no_plot: bool,
    cpm_url: str | None,
    cpm_station_id: int,
) -> None:
    """Scenario → captures → two sensor pipelines → signed UDP → backend: table, map, JSONL."""
    console = Console()
    if console.width < 100:
        # the table needs about 100 columns; pipes and narrow terminals wrap instead
        console = Console(width=100)
    result = run_demo(
        scenario,
        out_dir,
        reaction_s=reaction_s,
        plot=not no_plot,
        progress=lambda msg: console.print(f"[dim]{msg}[/dim]"),
        cpm_url=cpm_url,
        cpm_station_id=cpm_station_id,
    )
    console.print(_table(result, every_s))
    c = result.counters
    frames = sum(c["frames"].values())
    bearings = sum(c["bearings"].values())
    sent = sum(c["messages_sent"].values())
    rx = c["receiver"]
    rejected = sum(v for k, v in rx.items() if k.startswith("rejected"))
    console.print(
        f"frames {frames} → bearings {bearings} → signed messages {sent} → verified "
        f"{rx.get('verified', 0)} (rejected {rejected}) → fixes "
        f"{sum(v for k, v in c['backend'].items() if k.startswith('fixes.'))}"
    )
    d = result.decisive
    if d is not None:
        verdict = "within" if d.mahalanobis <= 3.0 else "OUTSIDE"
        console.print(
            f"fix behind the first BRAKE: error {d.error_m:.1f} m = {d.mahalanobis:.2f} σ, "
            f"{verdict} the reported 3σ; trustworthy fixes within 3σ: "
            f"{result.within_3sigma:.0%} of {len(result.ok_rows)}"
        )
    if result.first_brake_s is not None and result.brake_gap_m is not None:
        stops = result.brake_gap_m >= result.stop_needed_m
        console.print(
            f"first BRAKE advisory at {result.first_brake_s:.1f} s, car front "
            f"{result.brake_gap_m:.0f} m from the pedestrian; it needs "
            f"{result.stop_needed_m:.0f} m ({reaction_s:g} s reaction + 0.47 g): "
            + ("stops in time" if stops else "too late to stop, but it brakes")
        )
    if result.brake_needed_by_s is not None:
        console.print(
            f"to stop short the car needed the advisory by {result.brake_needed_by_s:.1f} s"
        )
    else:
        console.print("no BRAKE advisory was issued")
    lat = result.latency_ms
    console.print(
        f"frame arrival → assessment per 0.1 s step: median {np.median(lat):.1f} ms, "
        f"p99 {np.percentile(lat, 99):.1f} ms; whole demo {result.wall_s:.1f} s"
    )
    if "cpm" in c:
        cpm = c["cpm"]
        console.print(
            f"CPMs to {cpm_url}: generated {cpm['cpm.generated']}, sent {cpm['cpm.sent']}, "
            f"dropped {cpm['cpm.dropped']}"
        )
    for role, path in result.files.items():
        console.print(f"  {role}: {path}")
