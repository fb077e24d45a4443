"""``rfsas board``: find DF boards, ask one who it is, or emulate one."""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import signal
import tempfile
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from rfsas_hw.board.emulator import BoardEmulator, CaptureFeed, Emitter, MeasurementFeed, Scenario
from rfsas_hw.board.faults import Faults
from rfsas_hw.board.messages import Capability, Measurement, MeasurementBatch
from rfsas_hw.board.reader import FrameReader
from rfsas_hw.board.transport import EmulatorRunner, PtyEndpoint, TcpEndpoint
from rfsas_hw.cli.options import json_option
from rfsas_hw.errors import ConfigError, DataFormatError, SourceError

log = logging.getLogger(__name__)

DEFAULT_EMITTERS = ("-20,25,6,30", "30,40,6,30")


@click.group()
def board() -> None:
    """DF boards on serial lines: list ports, query a board, emulate one."""


@board.command("list")
def list_ports() -> None:
    """Serial ports that could hold a DF board (USB serial adapters first)."""
    from serial.tools import list_ports as lp

    ports = sorted(lp.comports(), key=lambda p: (p.vid is None, p.device))
    if not ports:
        click.echo("no serial ports found")
        return
    table = Table(title="Serial ports")
    for col in ("device", "description", "USB id", "serial number"):
        table.add_column(col)
    for p in ports:
        usb = f"{p.vid:04x}:{p.pid:04x}" if p.vid is not None else "—"
        table.add_row(p.device, p.description or "—", usb, p.serial_number or "—")
    Console().print(table)


@board.command("info")
@click.argument("url")
@click.option(
    "--baud",
    type=click.IntRange(min=1),
    default=921_600,
    show_default=True,
    help="Line rate, bit/s.",
)
@click.option(
    "--timeout",
    type=click.FloatRange(min=0, min_open=True),
    default=0.5,
    show_default=True,
    help="Seconds to wait per answer.",
)
@json_option("Print one JSON object instead of a table.")
def info(url: str, baud: int, timeout: float, as_json: bool) -> None:
    """Handshake with the board at URL (device path or pyserial URL) and show what it says.

    Use spy://DEVICE to see every byte on stderr.
    """
    from rfsas_hw.sources.serial_board import board_info

    msg, facts = board_info(url, baudrate=baud, handshake_timeout_s=timeout)
    caps = [c.name for c in Capability if c and c & msg.capabilities and c.name]
    rtt = facts["best_rtt_us"]
    if as_json:
        record = {
            "url": url,
            "protocol_version": msg.protocol_version,
            "firmware": msg.firmware,
            "board_id": f"{msg.board_id:016x}",
            "antennas": msg.n_antennas,
            "capabilities": caps,
            "best_rtt_us": rtt,
            "clock_offset_ns": facts["clock_offset_ns"],
        }
        click.echo(json.dumps(record))
        return
    table = Table(title=f"Board at {url}")
    table.add_column("field")
    table.add_column("value")
    table.add_row("protocol version", str(msg.protocol_version))
    table.add_row("firmware", msg.firmware)
    table.add_row("board id", f"{msg.board_id:016x}")
    table.add_row("antennas", str(msg.n_antennas))
    table.add_row("capabilities", ", ".join(caps) or "none")
    table.add_row("best round trip", "—" if rtt is None else f"{rtt:.0f} µs")
    zero = datetime.fromtimestamp(-facts["clock_offset_ns"] / 1e9, tz=UTC)
    table.add_row("board clock zero", zero.isoformat(timespec="milliseconds"))
    Console().print(table)


def _load_capture(capture: str, loop: bool) -> CaptureFeed:
    path = Path(capture)
    if path.suffix == ".bin" and path.exists():
        rows: list[Measurement] = []
        with path.open("rb") as fh:
            reader = FrameReader(fh, name=str(path))
            for _, msg in reader:
                if isinstance(msg, Measurement):
                    rows.append(msg)
                elif isinstance(msg, MeasurementBatch):
                    rows.extend(msg.measurements)
        if not rows:
            raise DataFormatError(f"{path}: no measurements in this board capture")
        return CaptureFeed(rows, loop=loop)
    from rfsas_hw.sources import open_source

    spec = capture if ":" in capture else f"pcap:{capture}"
    with open_source(spec) as src:
        batches = list(src)
    if not batches:
        raise DataFormatError(f"{capture}: no observations to replay")
    return CaptureFeed.from_observations(batches, loop=loop)


def check_link(link: Path) -> None:
    """``--link`` may be a new name or a stale link to a pseudo-terminal (an emulator that
    was killed leaves one); anything else is somebody's file, and the emulator would
    replace it and delete it when it stops.

    Raises:
        ConfigError: ``link`` exists and is not a symlink to ``/dev/pts/…``.
    """
    if not link.is_symlink() and not link.exists():
        return
    target = os.readlink(link) if link.is_symlink() else ""
    if not target.startswith("/dev/pts/"):
        raise ConfigError(
            f"--link {link} exists and is not a pseudo-terminal link; "
            "the emulator would replace and then delete it: choose a new name"
        )


@contextlib.contextmanager
def serving_endpoint(
    use_pty: bool, tcp: int | None, link: Path | None, prefix: str, name: str
) -> Iterator[PtyEndpoint | TcpEndpoint]:
    """The pty (default) or TCP endpoint an emulator serves on; closed, with its temp dir, after.

    Without ``link`` the pty's symlink ``name`` lives in a fresh temporary directory
    whose name starts with ``prefix``.

    Raises:
        ConfigError: both ``--pty`` and ``--tcp``, or a ``link`` that is not safe to use.
        SourceError: the pty cannot be created.
    """
    if use_pty and tcp is not None:
        raise ConfigError("give --pty or --tcp, not both")
    made_dir: Path | None = None
    endpoint: PtyEndpoint | TcpEndpoint
    if tcp is not None:
        endpoint = TcpEndpoint(tcp)
    else:
        if link is None:
            made_dir = Path(tempfile.mkdtemp(prefix=prefix))
            link = made_dir / name
        else:
            check_link(link)
        try:
            endpoint = PtyEndpoint(link)
        except OSError as err:
            if made_dir is not None:
                shutil.rmtree(made_dir, ignore_errors=True)
            raise SourceError(f"cannot create a pty at {link}: {err}") from err
    try:
        yield endpoint
    finally:
        endpoint.close()
        if made_dir is not None:
            shutil.rmtree(made_dir, ignore_errors=True)


@board.command("emulate")
@click.option("--pty", "use_pty", is_flag=True, help="Serve on a pseudo-terminal (the default).")
@click.option(
    "--tcp",
    type=click.IntRange(0, 65535),
    default=None,
    help="Serve on this TCP port (0: any free port).",
)
@click.option(
    "--link",
    type=click.Path(path_type=Path),
    default=None,
    help="Symlink to keep pointing at the pty (default: one in a fresh temp directory); "
    "must not exist, or be a link an earlier emulator left.",
)
@click.option(
    "--emitters",
    multiple=True,
    help="Emitter 'BEARING[,DISTANCE_M[,CHANNEL[,RATE_HZ]]]' or key=value list "
    "(bearing, distance, channel, rate, mac, radio); repeat or separate with ';'.",
)
@click.option("--capture", default=None, help="Replay a board .bin capture or a source spec.")
@click.option("--loop/--once", default=True, show_default=True, help="Repeat the capture.")
@click.option(
    "--fault",
    "faults",
    multiple=True,
    help="garbage=P, bitflip=P, drop=P (per frame), stall=EVERY_S:LEN_S, "
    "disconnect=EVERY_S:DOWN_S, seed=N.",
)
@click.option(
    "--baud",
    type=click.IntRange(min=0),
    default=921_600,
    show_default=True,
    help="Line rate to pace at (0: none).",
)
@click.option(
    "--batch",
    type=click.IntRange(min=1),
    default=1,
    show_default=True,
    help="Measurements per frame.",
)
@click.option("--seed", default=0, show_default=True, help="Seed of the RF scenario.")
@click.option(
    "--duration",
    type=click.FloatRange(min=0),
    default=None,
    help="Stop after this many seconds.",
)
def emulate(
    use_pty: bool,
    tcp: int | None,
    link: Path | None,
    emitters: tuple[str, ...],
    capture: str | None,
    loop: bool,
    faults: tuple[str, ...],
    baud: int,
    batch: int,
    seed: int,
    duration: float | None,
) -> None:
    """Run a software DF board; prints the device path (or socket URL) it serves on."""
    if capture and emitters:
        raise ConfigError("give --emitters or --capture, not both")
    feed: MeasurementFeed
    if capture:
        feed = _load_capture(capture, loop)
    else:
        specs = [s for e in (emitters or DEFAULT_EMITTERS) for s in e.split(";") if s.strip()]
        feed = Scenario([Emitter.parse(s, i) for i, s in enumerate(specs)], seed=seed)
    fault_plan = Faults.parse(faults)
    emulator = BoardEmulator(feed, batch_size=batch)
    with serving_endpoint(use_pty, tcp, link, "rfsas-board-", "ttyBOARD") as endpoint:
        # flushed at once: scripts read the path before the emulator ends
        print(endpoint.path, flush=True)
        click.echo(
            f"emulating a DF board on {endpoint.path} at {baud or 'unpaced'} baud; Ctrl-C stops",
            err=True,
        )
        runner = EmulatorRunner(emulator, endpoint, baud=baud or None, faults=fault_plan)
        # a terminated emulator still removes its pty link
        signal.signal(signal.SIGTERM, lambda *_: runner.stop_event.set())
        with contextlib.suppress(KeyboardInterrupt):
            runner.run(duration)
    c, r = emulator.counters, runner.stats
    click.echo(
        f"sent {c.frames_sent} frames ({c.measurements_sent} measurements, "
        f"{r.bytes_sent} bytes); dropped on board {c.frames_dropped}; "
        f"lost to overrun {r.overrun_bytes} bytes; frames damaged {runner.injector.touched}; "
        f"disconnects {r.disconnects}",
        err=True,
    )
