"""``rfsas city run``: a district in SUMO with RF-SAS off and on, through the broker, scored."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import click
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from rfsas_hw.cli.exitcodes import Interrupted, WorkFailed
from rfsas_hw.cli.outopts import OutputPath

if TYPE_CHECKING:
    from rfsas_hw.city.dashboard import CityDashboard
    from rfsas_hw.city.deploy import BrokerAccess
    from rfsas_hw.city.run import CityRunConfig, CityRunResult, District, Mode


@click.group()
def city() -> None:
    """A district: roadside units at its junctions, phones on its VRUs, every car advised."""


def _fmt(x: Any, digits: int = 2) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "—"
    return f"{x:.{digits}f}" if isinstance(x, float) else str(x)


NET_OPTION = click.option(
    "--net",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    default=None,
    help="SUMO net (default: Berlin-Adlershof from the eclipse-sumo wheel).",
)
ORIGIN_OPTION = click.option(
    "--origin",
    metavar="LAT,LON",
    default=None,
    help="Where a net without a projection (a generated grid) lies on the globe "
    "(default: Adlershof's centre); a geo-referenced net keeps its own.",
)
PLACEMENT_OPTION = click.option(
    "--placement",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    default=None,
    help="Placement YAML (default: two units per traffic light).",
)
BACKENDS_OPTION = click.option(
    "--backends",
    type=click.IntRange(1, 16),
    default=2,
    show_default=True,
    help="Backend processes (each owns a group of tiles).",
)


@city.command("keys")
@NET_OPTION
@ORIGIN_OPTION
@PLACEMENT_OPTION
@BACKENDS_OPTION
@click.option(
    "--out",
    "work_dir",
    type=OutputPath("dir"),
    required=True,
    help="Work folder (give it to rfsas city run --work): the identities go to its keys/.",
)
def keys(
    net: Path | None, origin: str | None, placement: Path | None, backends: int, work_dir: Path
) -> None:
    """Write the district's identities (one sensor per unit, the backends, the nonce
    authority; those already there are kept), so that a broker of your own can be given
    their certificates and ACL before rfsas city run --broker."""
    from rfsas_hw.backend.site import parse_origin
    from rfsas_hw.city.deploy import AUTHORITY_ID, GATEWAY_ID
    from rfsas_hw.city.live import LiveConfig
    from rfsas_hw.city.run import CityRunConfig, write_identities

    cfg = CityRunConfig(
        net=net,
        origin=None if origin is None else parse_origin(origin),
        placement=placement,
        live=replace(LiveConfig(), backends=backends),
    )
    ids = write_identities(cfg, work_dir)
    click.echo(f"{len(ids)} identities in {work_dir / 'keys'}")
    click.echo(
        f"broker files: rfsas broker config --keys {work_dir / 'keys' / AUTHORITY_ID} "
        f"--out BROKER --host HOST --port PORT --gateway {GATEWAY_ID}"
    )
    click.echo(
        f"then: rfsas city run --work {work_dir} --broker "
        f'"mqtts://HOST:PORT?ca=BROKER/ca/ca.crt&cert=BROKER/clients/{GATEWAY_ID}.crt'
        f'&key=BROKER/clients/{GATEWAY_ID}.key" …'
    )


@city.command("run")
@NET_OPTION
@ORIGIN_OPTION
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
@PLACEMENT_OPTION
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
@BACKENDS_OPTION
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
@click.option(
    "--deployment-nice",
    type=click.IntRange(0, 19),
    default=0,
    show_default=True,
    help="The twin workers, backends and vehicles' receivers run this many nice levels "
    "below the simulator, which stands for the physical world and never waits.",
)
@click.option(
    "--work",
    "work_dir",
    type=OutputPath("dir"),
    default=None,
    help="Where the deployment's identities (private keys: keep them out of --out) and, "
    "when the command starts mosquitto, the broker's files go; identities found there "
    "are kept (default: a temporary folder, deleted at the end).",
)
@click.option(
    "--broker",
    metavar="mqtts://HOST:PORT?ca=…&cert=…&key=…",
    default=None,
    help="Use this running broker instead of starting mosquitto: cert= and key= are the "
    "vehicles' gateway's; every other party's <id>.crt and <id>.key are taken from "
    "--broker-certs (see rfsas city keys and docs/city.md).",
)
@click.option(
    "--broker-certs",
    type=click.Path(exists=True, file_okay=False, path_type=Path),
    default=None,
    help="Folder with <id>.crt and <id>.key of every party, as rfsas broker config "
    "writes them (default: the folder of --broker's cert=).",
)
@click.option(
    "--web",
    metavar="[HOST:]PORT",
    default=None,
    help="Serve the live dashboard of the run with RF-SAS on here: every unit, every "
    "backend's fixes and tracks (default host 127.0.0.1; needs the web extra).",
)
@click.option(
    "--web-token",
    envvar="RFSAS_WEB_TOKEN",
    default=None,
    help="Token other hosts must give the dashboard [default: random when not on loopback].",
)
@click.option("--no-png", is_flag=True, help="Write the map as GeoJSON only.")
@click.option("--force", is_flag=True, help="Replace the files of an earlier run in --out.")
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
    deployment_nice: int,
    work_dir: Path | None,
    broker: str | None,
    broker_certs: Path | None,
    web: str | None,
    web_token: str | None,
    no_png: bool,
    force: bool,
) -> None:
    """Run a district: demand from SUMO's randomTrips, units at the traffic lights, and,
    with RF-SAS on, mosquitto with mutual TLS on loopback, a nonce authority, twin
    workers and tile-owning backends as processes, each car advised on its own topic
    and braking for its own BRAKE. Writes per mode a run log, a summary and a map."""
    from rfsas_hw.city.demand import DemandConfig
    from rfsas_hw.city.deploy import BrokerAccess
    from rfsas_hw.city.live import LiveConfig, prestart
    from rfsas_hw.city.run import CityRunConfig, check_run_outputs, prepare_district

    check_run_outputs(out_dir, _modes(modes), png=not no_png, force=force)
    if broker_certs is not None and broker is None:
        raise click.UsageError("--broker-certs goes with --broker")
    access = None if broker is None else BrokerAccess.from_url(broker, broker_certs)

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
            LiveConfig(),
            backends=backends,
            workers=workers,
            epoch_s=epoch_s,
            time_scale=time_scale,
            nice=deployment_nice,
        ),
    )
    console = Console(stderr=True)
    if modes != "off":
        prestart()
    district = prepare_district(cfg, out_dir)
    dashboard = None
    if web is not None and modes != "off":
        from rfsas_hw.city.dashboard import CityDashboard

        dashboard = CityDashboard(district.units, district.info.origin, web, web_token)
        click.echo(f"dashboard at {dashboard.url}", err=True)
    try:
        results = _runs(
            cfg, out_dir, district, modes, console, not no_png, work_dir, access, dashboard
        )
    finally:
        if dashboard is not None:
            dashboard.close()
    console.print(_table(results))
    for mode, res in results.items():
        click.echo(f"{mode}: " + ", ".join(str(p) for p in res.files.values()))
    problems = [p for r in results.values() for p in r.runtime.problems]
    if problems:
        raise WorkFailed("; ".join(problems[:5]))
    stopped = [(m, r) for m, r in results.items() if r.runtime.stopped != "end"]
    if stopped:
        mode, res = stopped[0]
        left = [m for m in _modes(modes) if m not in results]
        raise Interrupted(
            f"RF-SAS {mode} after {res.runtime.simulated_s:.1f} of {cfg.duration_s:g} simulated"
            " s (its log, summary and map are written"
            + (f"; RF-SAS {', '.join(left)} not run)" if left else ")")
        )


def _runs(
    cfg: CityRunConfig,
    out_dir: Path,
    district: District,
    modes: str,
    console: Console,
    png: bool,
    work_dir: Path | None,
    access: BrokerAccess | None,
    dashboard: CityDashboard | None,
) -> dict[str, CityRunResult]:
    """The runs ``--rfsas`` asks for, each with a progress bar."""
    from rfsas_hw.city.run import run_city

    results: dict[str, CityRunResult] = {}
    for mode in _modes(modes):
        columns = (
            TextColumn(f"RF-SAS {mode}"),
            BarColumn(),
            TextColumn("{task.fields[info]}"),
            TimeElapsedColumn(),
        )
        with Progress(*columns, console=console, transient=True) as bar:
            task = bar.add_task("run", total=cfg.duration_s, info="starting")

            def show(p: Any, task: Any = task, bar: Any = bar) -> None:
                bar.update(
                    task,
                    completed=p.t_s,
                    info=f"{p.vehicles} cars, {p.vrus} VRUs, {p.advisories} advisories "
                    f"({p.brakes} BRAKE), {p.realtime_factor:.2f}× real time",
                )

            results[mode] = result = run_city(
                cfg,
                out_dir,
                mode,
                district=district,
                on_progress=show,
                png=png,
                work_dir=work_dir,
                broker=access,
                dashboard=dashboard,
            )
        if result.runtime.stopped != "end":
            break  # interrupted: the next mode is not run
    return results


def _modes(rfsas: str) -> tuple[Mode, ...]:
    """The runs ``--rfsas`` asks for, in the order they run."""
    return ("off", "on") if rfsas == "both" else (cast("Mode", rfsas),)


def _table(results: dict[str, CityRunResult]) -> Table:
    from rfsas_hw.city.scoring import LATENCY_PARTS

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
            "  p99 of each part: to the backend's step / judging / delivery, ms",
            lambda r: " / ".join(
                _fmt(r.summary.latency_parts_ms.get(part, {}).get("p99"), 1)
                for part in LATENCY_PARTS
            ),
        ),
        (
            "linkability: longest linked stretch p50 / max, s",
            lambda r: (
                f"{_fmt(r.summary.linkability.get('p50_s'), 0)} / "
                f"{_fmt(r.summary.linkability.get('max_s'), 0)}"
            ),
        ),
        ("real-time factor", lambda r: r.runtime.realtime_factor),
        (
            "log records (in the run log)",
            lambda r: (
                ", ".join(f"{k} {v}" for k, v in sorted(r.runtime.log_records.items())) or "none"
            ),
        ),
    ]
    for name, get in rows:
        table.add_row(name, *(_fmt(get(r)) for r in results.values()))
    return table
