"""Options and building blocks shared by the commands that run a sensor (``replay``, ``live``).

A command adds :func:`sensor_options`, maps the values onto a
:class:`~rfsas_hw.apps.sensor.SensorAppConfig` with :func:`sensor_config` and
runs the :class:`~rfsas_hw.apps.sensor.SensorApp`; a new output is one option
here and one field of the application, and every sensor command gets it.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, TypeVar

import click
from rich.console import Console
from rich.progress import BarColumn, DownloadColumn, Progress, TimeRemainingColumn
from rich.table import Table

from rfsas_hw.apps.sensor import SensorApp, SensorAppConfig
from rfsas_hw.backend.site import parse_origin, pose_from_mapping
from rfsas_hw.cli.exitcodes import Interrupted, WorkFailed
from rfsas_hw.cli.linkopts import kept_link_options, send_options, split_urls
from rfsas_hw.cli.options import json_option, out_option
from rfsas_hw.cli.ros2opts import ros2_config
from rfsas_hw.df.fovguard import PROVE_MOTION_DEG
from rfsas_hw.errors import ConfigError
from rfsas_hw.outpaths import STDIO
from rfsas_hw.privacy.epochs import DEFAULT_EPOCH_S
from rfsas_hw.records import Pose
from rfsas_hw.runner import RunSummary

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
        out_option(
            "Write bearings here: .jsonl or .csv (or set --format); - for standard "
            "output (the summary then goes to stderr). An existing file needs --force."
        ),
        click.option(
            "--force", is_flag=True, help="Replace an existing --out file (never an input)."
        ),
        json_option(
            "Print the end-of-run summary as one JSON object instead of a table.",
            dest="json_summary",
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
            "--prove-motion",
            "prove_motion_deg",
            type=click.FloatRange(min=0.0, max=90.0),
            default=None,
            metavar="DEG",
            help="An emitter's bearings count once its bearing has swept this far, so that "
            "a static emitter behind or beside a fixed sensor gives none (nor one in "
            f"front). Default: {PROVE_MOTION_DEG:g} on a fixed mount, off with "
            "--moving-mount; 0: off.",
        ),
        click.option(
            "--moving-mount",
            is_flag=True,
            help="The sensor moves (a vehicle, a robot): no motion rule unless "
            "--prove-motion asks for it (an emitter on a collision course keeps its bearing).",
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


def sensor_config(
    spec: str,
    *,
    source_options: dict[str, Any],
    inputs: Iterable[str | Path],
    calibration_path: Path | None,
    out: Path | None,
    force: bool,
    epoch_s: float,
    fmt: str | None,
    sensor_id: str,
    pose: str,
    origin: str | None,
    min_snr_db: float | None,
    nonce_secret: Path | None,
    send: str | None,
    prove_motion_deg: float | None = None,
    moving_mount: bool = False,
    keys_dir: Path | None,
    ros2: dict[str, Any],
    **specific: Any,
) -> SensorAppConfig:
    """The :class:`~rfsas_hw.apps.sensor.SensorAppConfig` that the values of
    :func:`sensor_options` (and the ROS 2 options) ask for; ``specific``: the command's
    own fields of it (``duration_s``, ``realtime``, ``nonces`` …).

    Raises:
        ConfigError: a bad ``--pose`` or ``--origin``.
    """
    fallback, send_cues = kept_link_options()
    return SensorAppConfig(
        spec=spec,
        source_options=source_options,
        calibration=calibration_path,
        sensor_id=sensor_id,
        pose=parse_pose(pose, origin),
        min_snr_db=min_snr_db,
        prove_motion_deg=prove_motion_deg,
        moving_mount=moving_mount,
        epoch_s=epoch_s,
        nonce_secret=nonce_secret,
        keys_dir=keys_dir,
        out=out,
        fmt=fmt,
        force=force,
        inputs=tuple(str(i) for i in inputs if str(i)),
        send=tuple(split_urls(send)) if send is not None else (),
        fallback=fallback,
        send_cues=send_cues,
        ros2=ros2_config(ros2),
        **specific,
    )


def start_sensor(config: SensorAppConfig) -> SensorApp:
    """The sensor application of ``config``, telling the user where its live outputs are.

    Raises:
        See :class:`~rfsas_hw.apps.sensor.SensorApp`.
    """
    app = SensorApp(config)
    for line in app.notes:
        click.echo(line, err=True)
    return app


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
    "may_be_outside": "every bearing may come from outside the field of view; on a fixed "
    "mount an emitter counts once its bearing has swept, so emitters that stand still give "
    "none (replay such a capture with --prove-motion 0; a sensor that moves: --moving-mount)",
}


def _hint(reason: str, extra: dict[str, Any]) -> str:
    """What to do about the commonest rejection, naming the option a CSI file lacks."""
    fmt, unit = str(extra.get("csi_format", "")), str(extra.get("rssi_unit", "dBm"))
    if reason == "saturated" and fmt and unit.startswith("dB "):
        return (
            f"the {fmt} file's RSSI is on the tool's relative scale ({unit}), not dBm: "
            "give csi:FILE?rssi_offset=DB (the card's noise floor, e.g. -95)"
        )
    if reason == "no_table" and fmt in ("intel5300", "feitcsi"):
        return (
            f"the {fmt} file does not record the channel: give csi:FILE?freq=MHz "
            "(e.g. ?freq=2437 for channel 6)"
        )
    if reason == "missing_chain" and unit.startswith("none"):
        return (
            f"the {fmt} file records no RSSI ({unit}), so there is no amplitude pair: "
            "use a calibration with a phase section (rfsas calibrate --phase) or capture "
            "with firmware that writes the new format"
        )
    return _HINTS.get(reason, reason)


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
            first = f"; first: {summary.errors[0]}" if summary.errors else ""
            return f"0 bearings: none of {summary.frames:,} frames was usable ({reasons}){first}"
        if summary.errors:  # nothing read at all: a network unit not reached, say why
            more = len(summary.errors) - 1
            also = f" (and {more} more error(s))" if more else ""
            return f"0 bearings: nothing was read: {summary.errors[0]}{also}"
        repeats = int(summary.extra.get("repeats", 0) or 0)
        if repeats:
            return (
                f"0 bearings: the input gave the same frame {repeats:,} time(s) and no new "
                "one (its timestamps do not advance)"
            )
        return "0 bearings: the input held no frames"
    if not summary.rejected:
        return f"0 bearings from {summary.observations:,} observations"
    reason, count = summary.rejected.most_common(1)[0]
    hint = _hint(reason, summary.extra)
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
