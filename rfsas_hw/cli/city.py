"""``rfsas city run``: a district in SUMO with RF-SAS off and on, through the broker, scored."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from rfsas_hw.cli.exitcodes import WorkFailed
from rfsas_hw.cli.outopts import OutputPath

if TYPE_CHECKING:
    from rfsas_hw.city.run import CityRunResult


@click.group()
def city() -> None:
    """A district: roadside units at its junctions, phones on its VRUs, every car advised."""


def _fmt(x: Any, digits: int = 2) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "—"
    return f"{x:.{digits}f}" if isinstance(x, float) else str(x)


@city.command("run")
@click.option(
    "--net",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    default=None,
    help="SUMO net (default: Berlin-Adlershof from the eclipse-sumo wheel).",
)
@click.option(
    "--origin",
    metavar="LAT,LON",
    default=None,
    help="Where a net without a projection (a generated grid) lies on the globe "
    "(default: Adlershof's centre); a geo-referenced net keeps its own.",
)
@click.option(
    "--out",
    "out_dir",
    type=OutputPath("dir"),
    required=True,
    help="Output directory: demand, run logs, summaries, maps.",
)
@click.option(
    "--duration",
    "duration_s",
    type=click.FloatRange(min=1.0),
    default=300.0,
    show_default=True,
    help="Simulated seconds.",
)
@click.option("--seed", type=int, default=1, show_default=True, help="Seed of demand, SUMO, twin.")
@click.option(
    "--vehicles", type=click.IntRange(0), default=500, show_default=True, help="Car trips."
)
@click.option(
    "--pedestrians",
    type=click.IntRange(0),
    default=800,
    show_default=True,
    help="Pedestrian trips.",
)
@click.option(
    "--bicycles", type=click.IntRange(0), default=200, show_default=True, help="Bicycle trips."
)
@click.option(
    "--depart-until",
    "end_s",
    type=click.FloatRange(min=1.0),
    default=None,
    help="Departures spread over [0, this) seconds (default: the duration).",
)
@click.option(
    "--phones",
    "phone_penetration",
    type=click.FloatRange(0.0, 1.0),
    default=0.9,
    show_default=True,
    help="Share of VRUs carrying a phone.",
)
@click.option(
    "--reckless",
    "reckless_share",
    type=click.FloatRange(0.0, 1.0),
    default=0.1,
    show_default=True,
    help="Share of VRUs crossing against the light.",
)
@click.option(
    "--placement",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    default=None,
    help="Placement YAML (default: two units per traffic light).",
)
@click.option(
    "--polygons",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    default=None,
    help="SUMO polygon file with buildings (default: from city blocks).",
)
@click.option(
    "--rfsas",
    "modes",
    type=click.Choice(["both", "on", "off"]),
    default="both",
    show_default=True,
    help="Run without RF-SAS, with it, or both on the same seed.",
)
@click.option(
    "--backends",
    type=click.IntRange(1, 16),
    default=2,
    show_default=True,
    help="Backend processes (each owns a group of tiles).",
)
@click.option(
    "--workers",
    type=click.IntRange(1, 16),
    default=2,
    show_default=True,
    help="Twin worker processes (each twins the units of some junctions).",
)
@click.option(
    "--epoch",
    "epoch_s",
    type=click.FloatRange(min=1.0),
    default=60.0,
    show_default=True,
    help="Nonce epoch, seconds.",
)
@click.option(
    "--active-share",
    type=click.FloatRange(0.0, 1.0),
    default=0.2,
    show_default=True,
    help="Share of phones in active use (data bursts every 0.1 s); the others "
    "are idle (a probe sweep every 5 s).",
)
@click.option(
    "--time-scale",
    type=click.FloatRange(0.01, 1.0),
    default=1.0,
    show_default=True,
    help="Simulated seconds per wall second of the deployment's clock (below 1 "
    "for a machine that cannot keep up; real time only at 1).",
)
@click.option("--no-png", is_flag=True, help="Write the map as GeoJSON only.")
def run(
    net: Path | None,
    origin: str | None,
    out_dir: Path,
    duration_s: float,
    seed: int,
    vehicles: int,
    pedestrians: int,
    bicycles: int,
    end_s: float | None,
    phone_penetration: float,
    reckless_share: float,
    placement: Path | None,
    polygons: Path | None,
    modes: str,
    backends: int,
    workers: int,
    epoch_s: float,
    active_share: float,
    time_scale: float,
    no_png: bool,
) -> None:
    """Run a district: demand from SUMO's randomTrips, units at the traffic lights, and,
    with RF-SAS on, mosquitto with mutual TLS on loopback, a nonce authority, twin
    workers and tile-owning backends as processes, each car advised on its own topic
    and braking for its own BRAKE. Writes per mode a run log, a summary and a map."""
    from rfsas_hw.city.demand import DemandConfig
    from rfsas_hw.city.live import LiveConfig
    from rfsas_hw.city.run import CityRunConfig, run_city

    demand = DemandConfig(
        vehicles=vehicles,
        pedestrians=pedestrians,
        bicycles=bicycles,
        end_s=end_s if end_s is not None else duration_s,
        phone_penetration=phone_penetration,
        reckless_share=reckless_share,
        device_mix={"phone-active": active_share, "phone-idle": 1.0 - active_share},
    )
    from rfsas_hw.backend.site import parse_origin

    cfg = CityRunConfig(
        net=net,
        origin=None if origin is None else parse_origin(origin),
        demand=demand,
        placement=placement,
        polygons=polygons,
        duration_s=duration_s,
        seed=seed,
        live=replace(
            LiveConfig(), backends=backends, workers=workers, epoch_s=epoch_s, time_scale=time_scale
        ),
    )
    console = Console(stderr=True)
    results: dict[str, CityRunResult] = {}
    for mode in ("off", "on") if modes == "both" else (modes,):
        columns = (
            TextColumn(f"RF-SAS {mode}"),
            BarColumn(),
            TextColumn("{task.fields[info]}"),
            TimeElapsedColumn(),
        )
        with Progress(*columns, console=console, transient=True) as bar:
            task = bar.add_task("run", total=duration_s, info="starting")

            def show(p: Any, task: Any = task, bar: Any = bar) -> None:
                bar.update(
                    task,
                    completed=p.t_s,
                    info=f"{p.vehicles} cars, {p.vrus} VRUs, {p.advisories} advisories "
                    f"({p.brakes} BRAKE), {p.realtime_factor:.2f}× real time",
                )

            results[mode] = run_city(
                cfg,
                out_dir,
                mode,
                on_progress=show,
                png=not no_png,
            )
    console.print(_table(results))
    for mode, res in results.items():
        click.echo(f"{mode}: " + ", ".join(str(p) for p in res.files.values()))
    problems = [p for r in results.values() for p in r.runtime.problems]
    if problems:
        raise WorkFailed("; ".join(problems[:5]))


def _table(results: dict[str, CityRunResult]) -> Table:
    table = Table(title="district run")
    table.add_column("measure")
    for mode in results:
        table.add_column(f"RF-SAS {mode}", justify="right")
    rows: list[tuple[str, Any]] = [
        ("conflicts", lambda r: r.summary.conflicts),
        (
            "  by class",
            lambda r: ", ".join(f"{k} {v}" for k, v in r.summary.conflicts_by_class.items()),
        ),
        ("conflicts defused", lambda r: r.summary.conflicts_defused),
        ("collisions", lambda r: r.summary.collisions),
        ("nuisance BRAKEs / 100 veh-km", lambda r: r.summary.nuisance_per_100_vehicle_km),
        ("coverage (share at kerb)", lambda r: r.summary.coverage_share),
        ("fix error at kerb p50, m", lambda r: r.summary.coverage_error_p50_m),
        ("advisories / s", lambda r: r.summary.advisories_per_s),
        ("bearing messages / s", lambda r: r.summary.messages_per_s),
        (
            "latency p50 / p99, ms",
            lambda r: f"{_fmt(r.summary.latency_p50_ms, 1)} / {_fmt(r.summary.latency_p99_ms, 1)}",
        ),
        (
            "linkability: longest linked stretch p50 / max, s",
            lambda r: (
                f"{_fmt(r.summary.linkability.get('p50_s'), 0)} / "
                f"{_fmt(r.summary.linkability.get('max_s'), 0)}"
            ),
        ),
        ("real-time factor", lambda r: r.runtime.realtime_factor),
    ]
    for name, get in rows:
        table.add_row(name, *(_fmt(get(r)) for r in results.values()))
    return table
