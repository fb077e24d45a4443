"""``rfsas export``: turn a recorded run (JSON lines) into another format.

Each format is one entry of :data:`FORMATS`: a function taking the parsed
options and returning the lines to print. Adding a format is one function
and one entry.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from rfsas_hw.cli.exitcodes import WorkFailed
from rfsas_hw.cli.exportmaps import export_map
from rfsas_hw.cli.options import out_option
from rfsas_hw.cli.sensoropts import parse_pose
from rfsas_hw.cli.v2x import export_cpm
from rfsas_hw.errors import ConfigError
from rfsas_hw.outpaths import check_output
from rfsas_hw.records import Pose


def parse_sensor_poses(items: tuple[str, ...]) -> dict[str, Pose]:
    """``ID=X,Y,HEADING`` options to poses by sensor id.

    Raises:
        ConfigError: an item without ``=`` or with a bad pose.
    """
    out: dict[str, Pose] = {}
    for item in items:
        sensor_id, sep, pose = item.partition("=")
        if not sep or not sensor_id:
            raise ConfigError(f"--pose {item!r}: expected SENSOR_ID=X_M,Y_M,HEADING_DEG")
        out[sensor_id] = parse_pose(pose)
    return out


def _export_ros(runs: tuple[Path, ...], out: Path, fmt: str, opts: dict[str, Any]) -> list[str]:
    from rfsas_hw.ros2.export import export_runs

    result = export_runs(
        list(runs),
        out,
        fmt,  # type: ignore[arg-type]
        poses=parse_sensor_poses(opts["poses"]),
        storage=opts["storage"],
    )
    if not result.messages:
        skipped = sum(result.skipped.values())
        raise WorkFailed(
            f"nothing to export: 0 messages ({skipped} line(s) skipped"
            + (f", first: {result.errors[0]}" if result.errors else "")
            + "); give a run log of rfsas backend --out, or a bearings file of replay/live"
        )
    lines = [
        f"wrote {out}: {result.messages} messages on {len(result.counts)} topics",
        *(f"  {topic}: {n}" for topic, n in sorted(result.counts.items())),
    ]
    lines += [f"skipped {n} line(s): {reason}" for reason, n in sorted(result.skipped.items())]
    lines += [f"  {message}" for message in result.errors[:5]]
    if result.no_pose:
        lines.append(
            "no pose for sensor(s) "
            + ", ".join(sorted(result.no_pose))
            + ": their bearings are recorded, but no transform or ray (give --pose ID=X,Y,H)"
        )
    return lines


FORMATS: dict[str, Callable[[tuple[Path, ...], Path, str, dict[str, Any]], list[str]]] = {
    "mcap": _export_ros,
    "rosbag2": _export_ros,
    "geojson": export_map,
    "kml": export_map,
    "cot": export_map,
    "cpm": export_cpm,
}
"""Export function of each ``--to`` format."""

DEFAULT_SUFFIX = {
    "mcap": ".mcap",
    "geojson": ".geojson",
    "kml": ".kml",
    "cot": ".cot",
    "cpm": ".pcap",
}
"""Suffix of the default output file per format (rosbag2, a directory, has none)."""


@click.command("export")
@click.argument("runs", nargs=-1, required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--to", "fmt", required=True, type=click.Choice(sorted(FORMATS)), help="Format.")
@out_option(
    "Output file (a directory for rosbag2) [default: the run's name with the format's "
    "suffix; rosbag2 needs it].",
    kind="file_or_new_dir",
)
@click.option(
    "--pose",
    "poses",
    multiple=True,
    metavar="ID=X,Y,HEADING",
    help="mcap/rosbag2: pose of a sensor whose bearings carry none (a bearings file of "
    "rfsas replay/live); repeat per sensor.",
)
@click.option(
    "--storage",
    type=click.Choice(["sqlite3", "mcap"]),
    default="sqlite3",
    show_default=True,
    help="rosbag2: storage plugin of the bag.",
)
@click.option(
    "--origin",
    metavar="LAT,LON[,HEIGHT]",
    help="geojson/kml/cot/cpm: the site origin (WGS-84 degrees, ellipsoid metres) when the "
    "run log carries none, or to override it.",
)
@click.option("--flagged", is_flag=True, help="geojson/kml/cot: also export flagged fixes.")
@click.option("--force", is_flag=True, help="Replace an existing output file (never an input).")
def export(
    runs: tuple[Path, ...],
    fmt: str,
    out: Path | None,
    poses: tuple[str, ...],
    storage: str,
    origin: str | None,
    flagged: bool,
    force: bool,
) -> None:
    """Export RUNS (JSON lines of rfsas backend, replay or live) as FMT.

    \b
    rfsas export run.jsonl --to mcap --out run.mcap
    rfsas export bearings.jsonl --to rosbag2 --out run_bag --pose rsu-1=0,0,90
    rfsas export run.jsonl --to geojson        # writes run.geojson
    rfsas export run.jsonl --to kml --out run.kml --origin 52.2053,0.1218
    rfsas export run.jsonl --to cpm            # writes run.pcap (GeoNetworking CPMs)
    """
    if out is None:
        if fmt not in DEFAULT_SUFFIX:
            raise click.UsageError(f"--to {fmt} needs --out")
        out = runs[0].with_suffix(DEFAULT_SUFFIX[fmt])
        if out == runs[0]:
            raise click.UsageError(f"{out} is the input; give --out")
        # the default name is not an option value: checked here as the options are
        check_output(out, runs, force=force)
    opts = {"poses": poses, "storage": storage, "origin": origin, "flagged": flagged}
    for line in FORMATS[fmt](runs, out, fmt, opts):
        click.echo(line)
