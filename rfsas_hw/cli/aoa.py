"""``rfsas aoa``: emulate angle-of-arrival units (u-blox anchors, KrakenSDR) for tests and demos."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable
from pathlib import Path

import click

from rfsas_hw.cli.aoa_bleiq import emulate_bleiq
from rfsas_hw.cli.board import serving_endpoint
from rfsas_hw.sources.kraken_emulator import KrakenEmulator, KrakenServer, Vfo
from rfsas_hw.sources.ublox_emulator import Tag, UbloxEmulator, UbloxServer

DEFAULT_TAGS = ("CCF9578E0D8A,20,-55", "6C1DEBA5F60C,-35,-70")
DEFAULT_VFOS = ("433.92,45", "446.00625,300")


@click.group()
def aoa() -> None:
    """Angle-of-arrival units that report finished bearings (ublox:, kraken: sources)."""


@aoa.group()
def emulate() -> None:
    """Run a software AoA unit; prints the URL a source reads it from."""


emulate.add_command(emulate_bleiq)

_seed_option = click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
_duration_option = click.option(
    "--duration", type=float, default=None, help="Stop after this many seconds."
)


def _serve(
    run: Callable[[float | None], None], stop: threading.Event, duration: float | None
) -> None:
    """Run an emulator until ``duration`` ends, Ctrl-C, or SIGTERM (which still lets it
    close its pty or port)."""
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with contextlib.suppress(KeyboardInterrupt):
        run(duration)


@emulate.command("ublox")
@click.option("--pty", "use_pty", is_flag=True, help="Serve on a pseudo-terminal (the default).")
@click.option(
    "--tcp",
    type=click.IntRange(0, 65535),
    default=None,
    help="Serve on this TCP port (0: any free port).",
)
@click.option(
    "--link",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Keep a symlink to the pty here; must not exist, or be a link an earlier emulator left.",
)
@click.option(
    "--tag",
    "tags",
    multiple=True,
    help="MAC,AZIMUTH[,RSSI] of a tag in view (repeatable); azimuth −90…90.",
)
@click.option(
    "--fields",
    type=click.Choice(["9", "10", "12"]),
    default="10",
    show_default=True,
    help="+UUDF field count of the emulated firmware.",
)
@click.option(
    "--rate",
    type=click.FloatRange(0, 1000, min_open=True),
    default=10.0,
    show_default=True,
    help="Events per tag per s (above 0, at most 1000).",
)
@click.option(
    "--noise",
    type=click.FloatRange(0, 180),
    default=2.0,
    show_default=True,
    help="Azimuth σ, degrees (0-180).",
)
@click.option("--garbage", type=float, default=0.0, help="Probability of a damaged line.")
@click.option("--binary", is_flag=True, help="Send binary output (a unit left in binary mode).")
@_seed_option
@_duration_option
def emulate_ublox(
    use_pty: bool,
    tcp: int | None,
    link: Path | None,
    tags: tuple[str, ...],
    fields: str,
    rate: float,
    noise: float,
    garbage: float,
    binary: bool,
    seed: int,
    duration: float | None,
) -> None:
    """A u-blox AoA anchor printing +UUDF events.

    \b
    rfsas aoa emulate ublox --tag CCF9578E0D8A,20 --fields 12
    rfsas live ublox:/tmp/rfsas-aoa-…/ttyUBLOX --out bearings.jsonl
    """
    emulator = UbloxEmulator(
        [Tag.parse(t) for t in tags or DEFAULT_TAGS],
        fields=int(fields),
        noise_deg=noise,
        garbage=garbage,
        binary=binary,
        seed=seed,
    )
    with serving_endpoint(use_pty, tcp, link, "rfsas-aoa-", "ttyUBLOX") as endpoint:
        print(endpoint.path, flush=True)
        click.echo(f"emulating a u-blox AoA anchor on {endpoint.path}; Ctrl-C stops", err=True)
        server = UbloxServer(emulator, endpoint, rate_hz=rate)
        _serve(server.run, server.stop_event, duration)
    click.echo(
        f"sent {emulator.events} events ({emulator.garbage_lines} damaged), "
        f"{server.bytes_sent} bytes",
        err=True,
    )


@emulate.command("kraken")
@click.option(
    "--tcp",
    "port",
    type=click.IntRange(0, 65535),
    default=0,
    show_default=True,
    help="HTTP port (0: any).",
)
@click.option(
    "--vfo",
    "vfos",
    multiple=True,
    help="FREQ_MHZ,BEARING[,CONFIDENCE] of a transmitter (repeatable); bearing 0…360.",
)
@click.option(
    "--rate",
    type=click.FloatRange(0, 1000, min_open=True),
    default=5.0,
    show_default=True,
    help="Frames per second (above 0, at most 1000).",
)
@click.option(
    "--noise",
    type=click.FloatRange(0, 180),
    default=2.0,
    show_default=True,
    help="Bearing σ, degrees (0-180).",
)
@click.option("--torn", type=float, default=0.0, help="Probability a poll gets a torn page.")
@click.option("--markup", is_flag=True, help="Serve an HTML page (the wrong output mode).")
@_seed_option
@_duration_option
def emulate_kraken(
    port: int,
    vfos: tuple[str, ...],
    rate: float,
    noise: float,
    torn: float,
    markup: bool,
    seed: int,
    duration: float | None,
) -> None:
    """A KrakenSDR serving DOA_value.html on 127.0.0.1.

    \b
    rfsas aoa emulate kraken --vfo 433.92,45 --torn 0.05
    rfsas live kraken:http://127.0.0.1:PORT/DOA_value.html --out bearings.jsonl
    """
    emulator = KrakenEmulator(
        [Vfo.parse(v) for v in vfos or DEFAULT_VFOS],
        noise_deg=noise,
        torn=torn,
        markup=markup,
        seed=seed,
    )
    server = KrakenServer(emulator, port, rate_hz=rate)
    print(server.url, flush=True)
    click.echo(f"emulating a KrakenSDR at {server.url}; Ctrl-C stops", err=True)
    _serve(server.run, server.stop_event, duration)
    click.echo(f"wrote {emulator.frames} frames ({emulator.torn_pages} torn polls)", err=True)
