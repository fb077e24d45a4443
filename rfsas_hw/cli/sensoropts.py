"""Options and building blocks shared by the commands that run a sensor (``replay``, ``live``).

A command adds :func:`sensor_options`, then calls :func:`build_pipeline` and
:func:`build_listeners`; a new output (another listener) is one option here
and one line in :func:`build_listeners`, and every sensor command gets it.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, TypeVar

import click
from rich.console import Console
from rich.progress import BarColumn, DownloadColumn, Progress, TimeRemainingColumn
from rich.table import Table

from rfsas_hw.backend.site import parse_origin, pose_from_mapping
from rfsas_hw.cli.exitcodes import Interrupted, WorkFailed
from rfsas_hw.cli.linkopts import make_cue_publisher, make_publisher, send_options
from rfsas_hw.cli.outopts import OutputPath
from rfsas_hw.cli.ros2opts import sensor_scene, wants_live
from rfsas_hw.df import load_calibration
from rfsas_hw.errors import ConfigError
from rfsas_hw.outpaths import STDIO, check_output
from rfsas_hw.output import BearingWriter
from rfsas_hw.pipeline import SensorPipeline
from rfsas_hw.privacy.epochs import DEFAULT_EPOCH_S, EpochSchedule
from rfsas_hw.privacy.hashing import DerivedNonces, FixedNonce, MacHasher, NonceProvider
from rfsas_hw.records import Pose
from rfsas_hw.runner import RunSummary
from rfsas_hw.stream import Fanout

F = TypeVar("F", bound=Callable[..., Any])

PROGRESS_MIN_BYTES = 4 * 1024 * 1024
"""Captures at least this large get a progress bar."""


def parse_pose(text: str, origin: str | None = None) -> Pose:
    """``"X,Y,HEADING"`` (metres east, metres north, compass degrees) to a :class:`Pose`,
    or ``"geo:LAT,LON,HEADING"`` (WGS-84 degrees) placed through ``origin``
    (``"LAT,LON[,HEIGHT]"``, the site origin).

    Raises:
        ConfigError: not three numbers, or a geodetic pose without a usable origin.
    """
    if text.startswith("geo:"):
        if origin is None:
            raise ConfigError(f"--pose {text!r}: a pose on the globe needs --origin LAT,LON")
        try:
            lat, lon, heading = (float(p) for p in text[4:].split(","))
        except ValueError as err:
            raise ConfigError(f"--pose {text!r}: expected geo:LAT_DEG,LON_DEG,HEADING_DEG") from err
        return pose_from_mapping(
            {"lat_deg": lat, "lon_deg": lon, "heading_deg": heading},
            parse_origin(origin),
            f"--pose {text!r}",
        )
    parts = text.split(",")
    try:
        x, y, heading = (float(p) for p in parts)
    except ValueError as err:
        raise ConfigError(f"--pose {text!r}: expected X_M,Y_M,HEADING_DEG, e.g. 0,0,90") from err
    if not all(math.isfinite(v) for v in (x, y, heading)):
        raise ConfigError(f"--pose {text!r}: every value must be a finite number")
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
            type=OutputPath(),
            help="Write bearings here: .jsonl or .csv (or set --format); - for standard "
            "output (the summary then goes to stderr). An existing file needs --force.",
        ),
        click.option(
            "--force", is_flag=True, help="Replace an existing --out file (never an input)."
        ),
        click.option(
            "--json",
            "json_summary",
            is_flag=True,
            help="Print the end-of-run summary as one JSON object instead of a table.",
        ),
        click.option(
            "--epoch",
            "epoch_s",
            type=click.FloatRange(min=1.0),
            default=DEFAULT_EPOCH_S,
            show_default=True,
            help="Nonce epoch length of the deployment, seconds (as the authority and "
            "backend use).",
        ),
        click.option(
            "--format",
            "fmt",
            type=click.Choice(["jsonl", "csv", "mcap", "rosbag2"]),
            help="Output format (mcap: also from a .mcap name; rosbag2: --out names a new "
            "directory).",
        ),
        click.option("--sensor-id", default="sensor-1", show_default=True, help="Id in bearings."),
        click.option(
            "--pose",
            default="0,0,0",
            show_default=True,
            help="Sensor position and boresight: X_M,Y_M,HEADING_DEG (compass), or "
            "geo:LAT_DEG,LON_DEG,HEADING_DEG with --origin.",
        ),
        click.option(
            "--origin",
            metavar="LAT,LON[,HEIGHT]",
            help="The site origin on WGS-84 that local metres start from (for --pose geo:…).",
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
    epoch_s: float = DEFAULT_EPOCH_S,
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
    hasher = MacHasher(nonces if nonces is not None else FixedNonce(os.urandom(32)), epoch_s)
    return SensorPipeline(calibration, hasher, sensor_id, pose, min_snr_db=min_snr_db)


def deployment_nonces(pipeline: SensorPipeline | None) -> NonceProvider | None:
    """The deployment's epoch nonces the pipeline hashes with (from the authority or a
    shared secret), which also pre-authenticate what ``--send`` sends (version-2
    messages); None for a per-run random key, which no receiver holds."""
    if pipeline is None or isinstance(pipeline.hasher.nonces, FixedNonce):
        return None
    return pipeline.hasher.nonces


def build_listeners(
    out: Path | None,
    fmt: str | None,
    send: str | None,
    keys_dir: Path | None,
    pose: Pose,
    *,
    inputs: Iterable[str | Path] = (),
    force: bool = False,
    epoch_s: float = DEFAULT_EPOCH_S,
    ros2: dict[str, Any] | None = None,
    preauth: NonceProvider | None = None,
) -> Fanout:
    """Every listener the options ask for (``ros2``: the options of
    :func:`rfsas_hw.cli.ros2opts.live_options`).

    Raises:
        ConfigError: no output at all, a bad output name, an output that is one of
            ``inputs``, or an existing output without ``force``.
        KeyStoreError / LinkError: ``--send`` cannot be set up.
    """
    fanout = Fanout()
    if out is None and send is None and not wants_live(ros2 or {}):
        raise ConfigError("nothing to do: give --out FILE and/or --send URL")
    if out is not None:
        check_output(out, inputs, force=force, what="--out")
    publisher = make_publisher(send, keys_dir, pose, epoch_s, preauth)
    cue_publisher = make_cue_publisher(keys_dir, pose, epoch_s)
    if out is not None:
        from rfsas_hw.ros2.outputs import sensor_recording

        recording = sensor_recording(out, fmt, lambda _sensor_id: pose)
        fanout.add(recording if recording is not None else BearingWriter(out, fmt))
    if publisher is not None:
        fanout.add(publisher)
    if cue_publisher is not None:
        fanout.add(cue_publisher)
    try:
        scene, lines = sensor_scene(ros2 or {}, lambda _sensor_id: pose)
    except Exception:
        fanout.close()
        raise
    if scene is not None:
        fanout.add(scene)
        for line in lines:
            click.echo(line, err=True)
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
    for key, value in sorted(summary.nonces.items()):
        table.add_row(f"nonce wait: {key.replace('_', ' ')}", f"{value:,}")
    table.add_row("emitters", f"{summary.emitters:,}")
    table.add_row("bearings", f"{summary.bearings:,}")
    for name, counters in summary.outputs.items():
        for key, value in counters.items():
            table.add_row(f"{name}: {key}", f"{value:,}")
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


def epoch_schedule(epoch_s: float) -> EpochSchedule:
    """The deployment's epochs for ``--epoch`` (default grace period, capped below half
    an epoch for short test epochs).

    Raises:
        ConfigError: the epoch length is not usable.
    """
    try:
        return EpochSchedule(epoch_s, min(5.0, epoch_s / 4))
    except ValueError as err:
        raise ConfigError(f"--epoch: {err}") from err


_HINTS = {
    "no_table": "the calibration has no table for the channels heard: fit one per channel "
    "heard, or one for all with rfsas calibrate --single-table",
    "outside_fov": "every ratio fell outside the calibration's field of view",
    "missing_chain": "frames carry no per-antenna RSSI (capture both chains; docs/sources)",
    "low_snr": "every frame was below --min-snr",
    "saturated": "every frame was at the calibration's saturation level",
    "nonce_expired": "no nonce arrived from the authority in time (check --nonces, --keys, "
    "--epoch and that the authority runs)",
    "nonce_unavailable": "no nonce arrived from the authority (check --nonces, --keys, "
    "--epoch and that the authority runs)",
    "hold_overflow": "frames waited for a nonce until the hold queue overflowed",
}


def failure(summary: RunSummary) -> str | None:
    """Why the run's declared work failed, or None: an output failed (write error,
    nothing sent), or it produced no bearings at all (with a hint from the reasons)."""
    if summary.problems:
        return "; ".join(summary.problems)
    if summary.bearings:
        return None
    if not summary.observations:
        if summary.frames:
            reasons = ", ".join(f"{k} {v:,}" for k, v in summary.skipped.most_common(3))
            return f"0 bearings: none of {summary.frames:,} frames was usable ({reasons})"
        return "0 bearings: the input held no frames"
    if not summary.rejected:
        return f"0 bearings from {summary.observations:,} observations"
    reason, count = summary.rejected.most_common(1)[0]
    hint = _HINTS.get(reason, reason)
    return f"0 bearings from {summary.observations:,} observations ({reason} {count:,}): {hint}"


def _json_safe(value: Any) -> Any:
    """``value`` with every non-finite float as None (bare NaN is not JSON)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    return value


def finish_run(
    summary: RunSummary,
    title: str,
    *,
    out: Path | None,
    json_summary: bool,
    interrupt_is_failure: bool,
) -> None:
    """Print the summary (a table, or JSON with ``--json``) and the first frame errors,
    then end with the run's exit code.

    The summary goes to stdout, or to stderr when the bearings go to stdout (``--out -``).

    Raises:
        WorkFailed: the declared work failed (exit 1), see :func:`failure`.
        Interrupted: Ctrl-C/SIGTERM ended a run that was meant to finish (exit 130).
    """
    err_console = Console(stderr=True)
    to_stderr = out is not None and str(out) == STDIO
    problem = failure(summary)
    if json_summary:
        record = summary.as_dict()
        record["ok"] = problem is None
        record["failure"] = problem
        click.echo(json.dumps(_json_safe(record), allow_nan=False), err=to_stderr)
    else:
        (err_console if to_stderr else Console()).print(summary_table(summary, title))
    print_errors(err_console, summary)
    if interrupt_is_failure and summary.stopped in ("interrupted", "terminated"):
        raise Interrupted(f"{summary.stopped} after {summary.bearings:,} bearings")
    if problem is not None:
        raise WorkFailed(problem)
