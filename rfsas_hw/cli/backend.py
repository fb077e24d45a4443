"""``rfsas backend``: receive signed bearings, locate emitters, judge collision risk live."""

from __future__ import annotations

import math
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import click
import numpy as np
from rich import box
from rich.console import Console
from rich.live import Live
from rich.table import Table

from rfsas_hw.backend.collision import THREAT_SIZES
from rfsas_hw.backend.service import (
    BackendConfig,
    BackendService,
    JsonlSink,
    ResultSink,
    load_backend_config,
)
from rfsas_hw.backend.site import parse_origin
from rfsas_hw.backend.vehicle import VehicleFeed, load_vehicle
from rfsas_hw.cli.exitcodes import WorkFailed
from rfsas_hw.cli.linkopts import join_urls, split_urls
from rfsas_hw.cli.outopts import OutputPath
from rfsas_hw.cli.ros2opts import attach_scene, ros2_options
from rfsas_hw.errors import ConfigError
from rfsas_hw.fleet.certname import check_certificate_names
from rfsas_hw.link import Receiver, ReceiverConfig, open_transport
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.outpaths import check_output
from rfsas_hw.privacy.epochs import DEFAULT_EPOCH_S, EpochSchedule
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
@click.option(
    "--keys",
    "keys_dir",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="The backend's key directory; its trust/ holds the enrolled sensors' cards.",
)
@click.option(
    "--vehicle",
    metavar="FILE|udp://HOST:PORT",
    help="Vehicle state: a YAML/JSON file, or a UDP port receiving JSON states.",
)
@click.option(
    "--out",
    type=OutputPath(),
    help="Write every fix and assessment as JSON lines (and a final stats line).",
)
@click.option(
    "--plot",
    type=OutputPath(),
    help="At the end, draw a map PNG with 2σ covariance ellipses (needs the plot extra).",
)
@click.option(
    "--duration",
    type=click.FloatRange(min=0, min_open=True),
    help="Stop after this many seconds (default: Ctrl-C).",
)
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
    advise: str | None,
    send_cues: str | None,
    cues_fallback: str | None,
    vehicle_id: str,
    tile_plan: Path | None,
    prior_file: Path | None,
    no_table: bool,
    **ros2: Any,
) -> None:
    """Receive signed bearings, triangulate emitters and judge collision risk live.

    Messages are verified against the enrolled sensors (forged, replayed, stale
    and late ones are counted, never used); bearings of one emitter from two or
    more sensors within the window become a fix with its covariance; fixes feed
    a track per emitter; every track is judged against the vehicle state.
    """
    inputs = [p for p in (config_file, site_map, vehicle) if p is not None]
    for target in (out, plot):
        if target is not None:  # an existing result is replaced: it is this run's output
            check_output(target, [*inputs, *Path(keys_dir).glob("**/*")], force=True)
    config = BackendConfig() if config_file is None else load_backend_config(config_file)
    assoc, enc = config.association, config.encounter
    config = replace(
        config,
        association=replace(
            assoc,
            window_s=assoc.window_s if window is None else window,
            epoch_s=assoc.epoch_s if epoch is None else epoch,
        ),
        encounter=replace(
            enc,
            threat_kind=enc.threat_kind if threat is None else threat,
            reaction_s=enc.reaction_s if reaction is None else reaction,
        ),
        site=replace(
            config.site,
            origin=config.site.origin if origin is None else parse_origin(origin),
            map=config.site.map if site_map is None else site_map,
        ),
    )
    if cot is not None and config.site.origin is None:
        raise ConfigError("--cot needs the site origin: --origin LAT,LON or site.origin")
    epoch = config.association.epoch_s
    store = KeyStore.open(keys_dir)
    trust = store.trust
    if len(trust) == 0:
        raise ConfigError(f"{keys_dir}: no enrolled sensors in trust/ (rfsas keys enroll)")
    state = None if vehicle is None or vehicle.startswith("udp://") else load_vehicle(vehicle)
    urls = split_urls(listen)
    check_certificate_names(urls, store.id, "--listen")
    check_certificate_names([u for u in (advise, send_cues) if u], store.id, "--advise/--send-cues")
    if tile_plan is not None:
        from rfsas_hw.fleet.tiles import load_tile_plan, with_tiles

        plan = load_tile_plan(tile_plan)
        urls = [with_tiles(u, plan, store.id) for u in urls]
    receiver = Receiver.listen(
        urls,
        trust,
        # with an authority enrolled, envelopes arriving on the link (a broker's
        # retained nonce topic) give the keys that pre-authenticate version-2 messages
        store.nonce_store(EpochSchedule(epoch, min(5.0, epoch / 4)))
        if trust.authorities()
        else None,
        config=ReceiverConfig(epoch_s=epoch, grace_s=min(5.0, epoch / 4)),
    )
    feed: VehicleFeed | None = None
    sinks: list[ResultSink] = []
    try:
        if vehicle is not None and vehicle.startswith("udp://"):
            feed = VehicleFeed.listen(vehicle)
        if out is not None and out.suffix.lower() != ".mcap":
            sinks.append(JsonlSink(out, origin=config.site.origin, bearings=True))
        if prior_file is not None:
            from rfsas_hw.backend.prior import PriorSink

            sinks.append(PriorSink(prior_file))
        if cot is not None and config.site.origin is not None:
            from rfsas_hw.exports.tak import CotSender

            sinks.append(CotSender(cot, config.site.origin))
        if advise is not None:
            if config.site.origin is None:
                raise ConfigError("--advise needs the site origin: --origin LAT,LON or site.origin")
            from rfsas_hw.fleet.advisory import AdvisorySink

            sinks.append(
                AdvisorySink.to_url(
                    advise,
                    store.signer(),
                    config.site.origin,
                    vehicle_id=vehicle_id,
                    epoch_s=epoch,
                )
            )
        if cues_fallback is not None and send_cues is None:
            raise ConfigError("--cues-fallback is the out-of-band path of --send-cues")
        if send_cues is not None:
            from rfsas_hw.backend.cuer import BackendCuer
            from rfsas_hw.link.fallback import FallbackSender
            from rfsas_hw.link.transport import Transport

            cue_link: Transport = open_transport(send_cues, "send")
            if cues_fallback is not None:
                try:
                    secondary = open_transport(cues_fallback, "send")
                except BaseException:
                    cue_link.close()
                    raise
                # a jammed channel is jammed both ways: what arrives late here says
                # what we send on the same channel arrives late too
                cue_link = FallbackSender(cue_link, secondary, alarm=lambda: receiver.latency.alarm)
            sinks.append(BackendCuer(store.signer(), cue_link, epoch_s=epoch))
    except Exception:
        for sink in sinks:
            sink.close()
        receiver.close()
        if feed is not None:
            feed.close()
        raise
    service = BackendService(config, vehicle=state, sinks=sinks)
    service.link_stats = receiver.counters
    try:
        ros2_out = attach_scene(service, out, ros2)
    except Exception:
        receiver.close()
        if feed is not None:
            feed.close()
        service.close()
        raise
    for line in ros2_out.lines:
        click.echo(line, err=True)
    vehicle_feed = feed or ros2_out.vehicle_feed
    dashboard = None
    if web is not None:
        from rfsas_hw.web import start_dashboard

        try:
            dashboard = start_dashboard(service, web, latency=receiver.latency, token=web_token)
        except Exception:
            receiver.close()
            if feed is not None:
                feed.close()
            service.close()
            raise
        click.echo(f"dashboard at {dashboard.url}", err=True)
    console = Console()
    click.echo(f"listening on {listen}; {len(trust)} enrolled sender(s)", err=True)
    started = time.monotonic()
    try:
        if no_table:
            service.run(receiver, duration_s=duration, vehicle_feed=vehicle_feed)
        else:
            with Live(render_table(service, False), console=console, auto_refresh=False) as live:

                def redraw(_: list[Assessment]) -> None:
                    live.update(render_table(service, receiver.latency.alarm), refresh=True)

                service.run(
                    receiver,
                    duration_s=duration,
                    vehicle_feed=vehicle_feed,
                    on_step=redraw,
                )
            console.print()
    except KeyboardInterrupt:
        click.echo("stopped", err=True)
    finally:
        if dashboard is not None:
            dashboard.stop()
        ros2_out.close()
        receiver.close()
        if feed is not None:
            feed.close()
        service.close()
    elapsed = time.monotonic() - started
    stats = service.all_stats()
    console.print(f"ran {elapsed:.1f} s: " + ", ".join(f"{k} {v}" for k, v in stats.items()))
    if out is not None and not service.problems():
        click.echo(f"wrote {out}")
    if plot is not None:
        from rfsas_hw.backend.plot import plot_map

        plot_map(
            plot,
            stations=service.stations,
            assessments=service.assessments.values(),
            fixes=service.fixes.values(),
            vehicle=service.vehicle,
        )
        click.echo(f"wrote {plot}")
    if service.problems():
        raise WorkFailed("; ".join(service.problems()))
