"""Exports of a backend run to the mapping tools operators already use.

``rfsas export run.jsonl --to geojson|kml|cot`` reads a run log record by
record (:meth:`~rfsas_hw.exports.run.RunLog.records`), places it on the globe
through the site origin (:class:`~rfsas_hw.exports.scene.SceneStream`) and
writes GeoJSON (RFC 7946), KML 2.2 or Cursor-on-Target events as it reads, in
memory bounded by the sensors and tracks, not by the log's length. Live CoT to a TAK server is a
backend result sink, :class:`~rfsas_hw.exports.tak.CotSender`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from rfsas_hw.errors import ExportError
from rfsas_hw.exports.cot import write_cot
from rfsas_hw.exports.geojson import write_geojson
from rfsas_hw.exports.kml import write_kml
from rfsas_hw.exports.run import RunLog
from rfsas_hw.exports.scene import SceneCounts, SceneStream
from rfsas_hw.geo import SiteOrigin

WRITERS: dict[str, tuple[str, Callable[[SceneStream, Path], Path]]] = {
    "geojson": (".geojson", write_geojson),
    "kml": (".kml", write_kml),
    "cot": (".cot", write_cot),
}
"""Format name → (file suffix, writer)."""

__all__ = ["WRITERS", "export_run"]


def export_run(
    run_path: str | Path,
    fmt: str,
    out: str | Path | None = None,
    *,
    origin: SiteOrigin | None = None,
    flagged: bool = False,
) -> tuple[Path, SceneCounts, RunLog]:
    """Export the run log at ``run_path`` as ``fmt`` (``geojson``, ``kml`` or ``cot``).

    Args:
        run_path: the backend's JSON-lines output (``rfsas backend --out``).
        fmt: the format.
        out: output file (default: the run's name with the format's suffix).
        origin: the site origin; overrides the one the log carries.
        flagged: also export fixes the backend flagged.

    Returns:
        The file written, what it holds and the log read (for its skip counters).

    Raises:
        ExportError: unknown format, unreadable log, no origin, or unwritable output.
    """
    if fmt not in WRITERS:
        raise ExportError(f"unknown export format {fmt!r}; one of {', '.join(WRITERS)}")
    suffix, writer = WRITERS[fmt]
    run = RunLog(source=str(Path(run_path)))
    scene = SceneStream(run.records(), run.origin_or(origin), flagged=flagged)
    target = Path(out) if out is not None else Path(run_path).with_suffix(suffix)
    return writer(scene, target), scene.counts(), run
