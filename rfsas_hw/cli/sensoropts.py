"""Options and building blocks shared by the commands that run a sensor (``replay``, ``live``).

A command adds :func:`sensor_options`, then calls :func:`build_pipeline` and
:func:`build_listeners`; a new output (another listener) is one option here
and one line in :func:`build_listeners`, and every sensor command gets it.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import click
from rich.console import Console
from rich.progress import BarColumn, DownloadColumn, Progress, TimeRemainingColumn
from rich.table import Table

from rfsas_hw.cli.linkopts import make_publisher, send_options
from rfsas_hw.df import load_calibration
from rfsas_hw.errors import ConfigError
from rfsas_hw.output import BearingWriter
from rfsas_hw.pipeline import SensorPipeline
from rfsas_hw.privacy.hashing import DerivedNonces, FixedNonce, MacHasher, NonceProvider
from rfsas_hw.records import Pose
from rfsas_hw.runner import RunSummary
from rfsas_hw.stream import Fanout

F = TypeVar("F", bound=Callable[..., Any])

PROGRESS_MIN_BYTES = 4 * 1024 * 1024
"""Captures at least this large get a progress bar."""


def parse_pose(text: str) -> Pose:
    """``"X,Y,HEADING"`` (metres east, metres north, compass degrees) to a :class:`Pose`.

    Raises:
        ConfigError: not three numbers.
    """
    parts = text.split(",")
    try:
        x, y, heading = (float(p) for p in parts)
    except ValueError as err:
        raise ConfigError(f"--pose {text!r}: expected X_M,Y_M,HEADING_DEG, e.g. 0,0,90") from err
    return Pose(x, y, heading % 360.0)


def sensor_options(func: F) -> F:
    """Add the options every sensor command shares (calibration, outputs, identity)."""
    options = [
        click.option(
            "--calibration",
            "calibration_path",
            default=None,
            type=click.Path(dir_okay=False, path_type=Path),
            help="Calibration YAML of the antenna pair (rfsas calibrate); "
            "required unless the source gives bearings itself (agrelo:).",
        ),
        click.option(
            "--out",
            "out",
            type=click.Path(dir_okay=False, path_type=Path),
            help="Write bearings here: .jsonl or .csv (or set --format).",
        ),
        click.option("--format", "fmt", type=click.Choice(["jsonl", "csv"]), help="Output format."),
        click.option("--sensor-id", default="sensor-1", show_default=True, help="Id in bearings."),
        click.option(
            "--pose",
            default="0,0,0",
            show_default=True,
            help="Sensor position and boresight: X_M,Y_M,HEADING_DEG (compass).",
        ),
        click.option(
            "--min-snr",
            "min_snr_db",
            type=float,
            help="Reject frames whose stronger antenna is below this SNR, dB.",
        ),
        click.option(
            "--errors",
            type=click.Choice(["skip", "raise"]),
            default="skip",
            show_default=True,
            help="Bad frames: skip and count them, or stop at the first.",
        ),
        click.option(
            "--nonce-secret",
            "nonce_secret",
            type=click.Path(dir_okay=False, path_type=Path),
            help="Derive epoch nonces from this shared secret (rfsas nonces secret), so that "
            "sensors given the same file produce the same emitter ids. "
            "Default: a random key per run.",
        ),
        send_options,
    ]
    for option in reversed(options):
        func = option(func)
    return func


def build_pipeline(
    calibration_path: Path | None,
    sensor_id: str,
    pose: Pose,
    min_snr_db: float | None,
    nonces: NonceProvider | None = None,
    nonce_secret: Path | None = None,
) -> SensorPipeline:
    """The pipeline hashing with ``nonces`` (the deployment's epoch nonces), with
    nonces derived from the secret in ``nonce_secret``, or by default with a
    per-run random key (ids unlinkable across runs).

    Raises:
        CalibrationError / ConfigError: the calibration file is unusable.
        KeyStoreError: the secret file is unreadable, too short or not private.
    """
    if nonces is not None and nonce_secret is not None:
        raise ConfigError("give --nonces or --nonce-secret, not both")
    if calibration_path is None:
        raise ConfigError("--calibration CAL.yaml is required to turn RSSI pairs into bearings")
    calibration = load_calibration(calibration_path)
    if nonce_secret is not None:
        nonces = DerivedNonces.from_file(nonce_secret)
    hasher = MacHasher(nonces if nonces is not None else FixedNonce(os.urandom(32)))
    return SensorPipeline(calibration, hasher, sensor_id, pose, min_snr_db=min_snr_db)


def build_listeners(
    out: Path | None,
    fmt: str | None,
    send: str | None,
    keys_dir: Path | None,
    pose: Pose,
) -> Fanout:
    """Every listener the options ask for.

    Raises:
        ConfigError: no output at all, or a bad output name.
        KeyStoreError / LinkError: ``--send`` cannot be set up.
    """
    fanout = Fanout()
    if out is None and send is None:
        raise ConfigError("nothing to do: give --out FILE and/or --send URL")
    publisher = make_publisher(send, keys_dir, pose)
    if out is not None:
        fanout.add(BearingWriter(out, fmt))
    if publisher is not None:
        fanout.add(publisher)
    return fanout


def summary_table(summary: RunSummary, title: str) -> Table:
    """The end-of-run summary as a table."""
    table = Table(title=title)
    table.add_column("quantity")
    table.add_column("value", justify="right")
    table.add_row("frames read", f"{summary.frames:,}")
    table.add_row("observations", f"{summary.observations:,}")
    for i, count in enumerate(summary.per_antenna):
        table.add_row(f"  with antenna {i} signal", f"{count:,}")
    table.add_row("  with every antenna (per-chain frames)", f"{summary.all_antennas:,}")
    for reason, count in sorted(summary.flagged.items()):
        table.add_row(f"  flagged: {reason}", f"{count:,}")
    for reason, count in sorted(summary.skipped.items()):
        table.add_row(f"skipped: {reason}", f"{count:,}")
    for reason, count in sorted(summary.rejected.items()):
        table.add_row(f"no bearing: {reason}", f"{count:,}")
    for key, value in sorted(summary.extra.items()):
        if isinstance(value, int | float | str):
            shown = f"{value:.3f}" if isinstance(value, float) else str(value)
            table.add_row(key.replace("_", " "), shown)
    table.add_row("emitters", f"{summary.emitters:,}")
    table.add_row("bearings", f"{summary.bearings:,}")
    table.add_row("capture span", f"{summary.capture_span_s:.1f} s")
    table.add_row("run time", f"{summary.elapsed_s:.2f} s")
    table.add_row("ended by", summary.stopped)
    return table


def print_errors(console: Console, summary: RunSummary, limit: int = 5) -> None:
    """The first few frame errors (with frame numbers and offsets)."""
    for message in summary.errors[:limit]:
        console.print(f"[yellow]skipped:[/yellow] {message}", highlight=False, soft_wrap=True)
    more = sum(summary.skipped.values()) - min(limit, len(summary.errors))
    if summary.errors and more > 0:
        console.print(f"… and {more:,} more skipped frames (see the table)", highlight=False)


def progress_bar(console: Console) -> Progress:
    """A byte-based progress bar for reading a capture file."""
    return Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        DownloadColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=True,
    )
