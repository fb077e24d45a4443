"""The map formats of ``rfsas export`` (geojson, kml, cot): a run log on the globe."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rfsas_hw.backend.site import parse_origin
from rfsas_hw.cli.exitcodes import WorkFailed
from rfsas_hw.errors import ConfigError
from rfsas_hw.exports import export_run


def export_map(runs: tuple[Path, ...], out: Path, fmt: str, opts: dict[str, Any]) -> list[str]:
    """Export one backend run log as GeoJSON, KML or CoT; the lines to print.

    ``opts``: ``origin`` (``"LAT,LON[,HEIGHT]"`` or None: the log's own) and
    ``flagged`` (also draw flagged fixes).

    Raises:
        ConfigError: more than one run, or a bad origin.
        ExportError: unreadable log, no origin, unwritable output.
    """
    if len(runs) != 1:
        raise ConfigError(f"--to {fmt} exports one run log at a time, got {len(runs)}")
    origin = parse_origin(opts["origin"]) if opts.get("origin") else None
    path, drawn, run = export_run(
        runs[0], fmt, out, origin=origin, flagged=bool(opts.get("flagged"))
    )
    if not (drawn.fixes or drawn.bearings or drawn.tracks):
        skipped = sum(run.skipped.values())
        raise WorkFailed(
            f"{runs[0]}: nothing to export (0 fixes, 0 bearings; {skipped} line(s) skipped"
            + (f", first: {run.errors[0]}" if run.errors else "")
            + "); give a run log of rfsas backend --out, or bearings with poses"
        )
    lines = [
        f"wrote {path}: {drawn.fixes} fixes, {drawn.bearings} bearings, "
        f"{drawn.tracks} tracks, {drawn.sensors} sensors"
    ]
    if not drawn.bearings:
        lines.append("no bearings in the log (run the backend with --out to record them)")
    for reason, n in sorted(run.skipped.items()):
        lines.append(f"skipped {n} line(s): {reason}")
    lines += [f"  {message}" for message in run.errors[:5]]
    return lines
