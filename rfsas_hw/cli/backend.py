"""``rfsas backend``: receive signed bearings, locate emitters, judge collision risk live."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import click
import numpy as np
from rich import box
from rich.console import Console
from rich.live import Live
from rich.table import Table

from rfsas_hw.apps.backend import BackendApp, BackendAppConfig, SettingsOverrides
from rfsas_hw.backend.collision import THREAT_SIZES
from rfsas_hw.backend.service import BackendService
from rfsas_hw.backend.site import parse_origin
from rfsas_hw.cli.exitcodes import WorkFailed
from rfsas_hw.cli.linkopts import join_urls, split_urls
from rfsas_hw.cli.options import duration_option, keys_option, out_option
from rfsas_hw.cli.outopts import OutputPath
from rfsas_hw.cli.ros2opts import ros2_config, ros2_options
from rfsas_hw.privacy.epochs import DEFAULT_EPOCH_S
from rfsas_hw.records import Assessment

ADVISORY_STYLE = {"brake": "bold red", "caution": "yellow", "clear": "green", "none": "dim"}


def _sigma_m(a: Assessment) -> float:
    cov = a.covariance
    if not np.isfinite(cov).all():
        return math.nan
    return float(math.sqrt(max(np.linalg.eigvalsh((cov + cov.T) / 2)[-1], 0.0)))


def _num(value: float, fmt: str) -> str:
    return "–" if not math.isfinite(value) else format(value, fmt)


def render_table(service: BackendService, alarm: bool) -> Table:
    """The live table: one row per emitter, highest risk first."""
    table = Table(title="rfsas backend", box=box.SIMPLE_HEAD)
    table.add_column("emitter", no_wrap=True)
    for col in ("position (m)", "± σ (m)", "age (s)"):
        table.add_column(col, justify="right", no_wrap=True)
    table.add_column("sensors")
    for col in ("P_coll", "risk"):
        table.add_column(col, justify="right", no_wrap=True)
    table.add_column("advisory", no_wrap=True)
    table.add_column("link", no_wrap=True)
    rows = sorted(
        service.assessments.values(),
        key=lambda a: -a.risk if math.isfinite(a.risk) else 1.0,
    )
    for a in rows:
        pos = "–" if not math.isfinite(a.x_m) else f"{a.x_m:7.1f}, {a.y_m:7.1f}"
        table.add_row(
            a.emitter,
            pos,
            _num(_sigma_m(a), ".1f"),
            f"{a.age_s:.1f}",
            ",".join(a.sensors),
            _num(a.p_collision, ".3f"),
            _num(a.risk, ".2e"),
            f"[{ADVISORY_STYLE.get(a.advisory, '')}]{a.advisory}[/]",
            "[bold red]ALARM[/]" if a.link_alarm else "ok",
        )
    s = service.stats
    table.caption = (
        f"messages {s.messages}  bearings {s.bearings}  fixes ok {s.fixes.get('ok', 0)}, "
        f"flagged {sum(s.fixes.values()) - s.fixes.get('ok', 0)}  "
        f"link {'ALARM' if alarm else 'ok'}"
    )
    return table


@click.command("backend")
@click.option(
    "--listen",
    required=True,
    multiple=True,
    callback=join_urls,
    metavar="URL",
    help="Where signed safety messages arrive: udp://HOST:PORT, or a broker "
    "(mqtts://HOST?ca=…&cert=…&key=…&tiles=…); repeat to take several at once.",
)
@keys_option("The backend's key directory; its trust/ holds the enrolled sensors' cards.")
@click.option(
    "--vehicle",
    metavar="FILE|udp://HOST:PORT",
    help="Vehicle state: a YAML/JSON file, or a UDP port receiving JSON states.",
)
@out_option("Write every fix and assessment as JSON lines (and a final stats line).")
@click.option(
    "--plot",
    type=OutputPath(),
    help="At the end, draw a map PNG with 2σ covariance ellipses (needs the plot extra).",
)
@duration_option()
@click.option(
    "--config",
    "config_file",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Backend settings in YAML (association, triangulation, tracker, encounter).",
)
@click.option(
    "--window",
    type=click.FloatRange(min=0, min_open=True),
    help="Association window, seconds, shorter than the nonce epoch [default: 1].",
)
@click.option(
    "--epoch",
    type=click.FloatRange(min=1.0),
    help=f"Nonce epoch length of the deployment, seconds [default: {DEFAULT_EPOCH_S:g}].",
)
@click.option(
    "--threat",
    type=click.Choice(sorted(THREAT_SIZES)),
    help="What the emitters are carried by; sets the threat box [default: pedestrian].",
)
@click.option(
    "--reaction",
    type=click.FloatRange(min=0),
    help="Reaction delay before braking, seconds [default: 0].",
)
@click.option(
    "--origin",
    metavar="LAT,LON[,HEIGHT]",
    help="Site origin on WGS-84 (overrides site.origin of --config): outputs carry "
    "latitude/longitude.",
)
@click.option(
    "--map",
    "site_map",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Buildings and roads for the dashboard: a scenario YAML or a GeoJSON file.",
)
@click.option(
    "--web",
    metavar="[HOST:]PORT",
    help="Serve the live dashboard here (default host 127.0.0.1; needs the web extra).",
)
@click.option(
    "--web-token",
    envvar="RFSAS_WEB_TOKEN",
    help="Token other hosts must give the dashboard [default: random when not on loopback].",
)
@click.option(
    "--cot",
    metavar="udp://HOST:PORT|tcp://HOST:PORT",
    help="Send fixes and tracks as Cursor-on-Target events to a TAK server (needs an origin).",
)
@click.option(
    "--cpm",
    metavar="URL",
    help="Send the tracks as ETSI Collective Perception Messages: udp://HOST:PORT[?btp=1] "
    "or mqtt(s)://HOST[:PORT]/TOPIC (needs the site origin and the v2x extra; docs/v2x.md).",
)
@click.option(
    "--cpm-station-id",
    type=click.IntRange(0, 2**32 - 1),
    default=1,
    show_default=True,
    help="StationId of this backend in its CPMs.",
)
@click.option(
    "--cpm-from-vehicle",
    is_flag=True,
    help="The CPMs come from the vehicle (--vehicle) rather than a roadside unit: "
    "the vehicle's position is their reference, its heading their orientation.",
)
@click.option(
    "--advise",
    metavar="mqtts://HOST?…",
    help="Publish signed assessments (advisories) to a broker, on the tile topics of "
    "the emitters and the vehicle's topic (needs the site origin).",
)
@click.option(
    "--send-cues",
    metavar="URL",
    help="Send signed fix cues for emitters at risk (risk >= 0.1) to the vehicles here, "
    "so that their sensors listen on the emitter's channel (docs/cueing.md).",
)
@click.option(
    "--cues-fallback",
    metavar="URL",
    help="Out-of-band path for --send-cues: cues move there while the latency watch of "
    "what this backend receives is in alarm, and back 2 s after it clears.",
)
@click.option(
    "--vehicle-id",
    default="",
    metavar="ID",
    help="Id of the vehicle judged against (its advisory topic).",
)
@click.option(
    "--tile-plan",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Tile plan (YAML): broker --listen URLs take the tiles of this backend's group.",
)
@click.option(
    "--prior",
    "prior_file",
    type=OutputPath("update"),
    help="RF activity prior file (counts per tile and hour, no emitter ids): read, or "
    "started when missing, counted with this run's fixes, written back when the run ends.",
)
@click.option(
    "--accept-v1",
    is_flag=True,
    help="Also accept version-1 messages (no pre-authentication tag) while an authority "
    "is enrolled: only for a fleet still migrating, since a version-1 flood under an "
    "enrolled id then spends that sensor's signature budget. Without an enrolled "
    "authority version 1 is the only kind that can be checked and is always accepted.",
)
@click.option("--no-table", is_flag=True, help="Do not draw the live table.")
@ros2_options
def backend(
    listen: str,
    keys_dir: Path,
    vehicle: str | None,
    out: Path | None,
    plot: Path | None,
    duration: float | None,
    config_file: Path | None,
    window: float | None,
    epoch: float | None,
    threat: str | None,
    reaction: float | None,
    origin: str | None,
    site_map: Path | None,
    web: str | None,
    web_token: str | None,
    cot: str | None,
    cpm: str | None,
    cpm_station_id: int,
    cpm_from_vehicle: bool,
    advise: str | None,
    send_cues: str | None,
    cues_fallback: str | None,
    vehicle_id: str,
    tile_plan: Path | None,
    prior_file: Path | None,
    accept_v1: bool,
    no_table: bool,
    **ros2: Any,
) -> None:
    """Receive signed bearings, triangulate emitters and judge collision risk live.

    Messages are verified against the enrolled sensors (forged, replayed, stale
    and late ones are counted, never used); bearings of one emitter from two or
    more sensors within the window become a fix with its covariance; fixes feed
    a track per emitter; every track is judged against the vehicle state.
    """
    config = BackendAppConfig(
        listen=tuple(split_urls(listen)),
        keys_dir=keys_dir,
        settings_file=config_file,
        overrides=SettingsOverrides(
            window_s=window,
            epoch_s=epoch,
            threat_kind=threat,
            reaction_s=reaction,
            origin=None if origin is None else parse_origin(origin),
            site_map=site_map,
        ),
        vehicle=vehicle,
        vehicle_id=vehicle_id,
        out=out,
        plot=plot,
        duration_s=duration,
        web=web,
        web_token=web_token,
        cot=cot,
        cpm=cpm,
        cpm_station_id=cpm_station_id,
        cpm_from_vehicle=cpm_from_vehicle,
        advise=advise,
        send_cues=send_cues,
        cues_fallback=cues_fallback,
        tile_plan=tile_plan,
        prior_file=prior_file,
        accept_v1=accept_v1,
        ros2=ros2_config(ros2),
    )
    app = BackendApp(config)
    for line in app.notes:
        click.echo(line, err=True)
    console = Console()
    click.echo(f"listening on {listen}; {app.enrolled} enrolled sender(s)", err=True)
    started = time.monotonic()
    with app:
        try:
            if no_table:
                app.run()
            else:
                _run_with_table(app, console)
        except KeyboardInterrupt:
            click.echo("stopped", err=True)
    elapsed = time.monotonic() - started
    stats = app.stats()
    console.print(f"ran {elapsed:.1f} s: " + ", ".join(f"{k} {v}" for k, v in stats.items()))
    if app.cpm_sink is not None:
        console.print(", ".join(f"{k} {v}" for k, v in app.cpm_sink.counters().items()))
    problems = app.service.problems()
    if out is not None and not problems:
        click.echo(f"wrote {out}")
    drawn = app.draw_map()
    if drawn is not None:
        click.echo(f"wrote {drawn}")
    if problems:
        raise WorkFailed("; ".join(problems))


def _run_with_table(app: BackendApp, console: Console) -> None:
    """Run ``app``, redrawing the live table after every step."""
    service, receiver = app.service, app.receiver
    with Live(render_table(service, False), console=console, auto_refresh=False) as live:

        def redraw(_: list[Assessment]) -> None:
            live.update(render_table(service, receiver.latency.alarm), refresh=True)

        app.run(on_step=redraw)
    console.print()
