"""Exports of a backend run to the mapping tools operators already use.

``rfsas export run.jsonl --to geojson|kml|cot`` reads a run log
(:func:`~rfsas_hw.exports.run.read_run`), places it on the globe through the
site origin (:func:`~rfsas_hw.exports.scene.build_scene`) and writes GeoJSON
(RFC 7946), KML 2.2 or Cursor-on-Target events. Live CoT to a TAK server is a
backend result sink, :class:`~rfsas_hw.exports.tak.CotSender`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from rfsas_hw.errors import ExportError
from rfsas_hw.exports.cot import write_cot
from rfsas_hw.exports.geojson import write_geojson
from rfsas_hw.exports.kml import write_kml
from rfsas_hw.exports.run import RunLog, read_run
from rfsas_hw.exports.scene import Scene, build_scene
from rfsas_hw.geo import SiteOrigin

WRITERS: dict[str, tuple[str, Callable[[Scene, Path], Path]]] = {
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
) -> tuple[Path, Scene, RunLog]:
    """Export the run log at ``run_path`` as ``fmt`` (``geojson``, ``kml`` or ``cot``).

    Args:
        run_path: the backend's JSON-lines output (``rfsas backend --out``).
        fmt: the format.
        out: output file (default: the run's name with the format's suffix).
        origin: the site origin; overrides the one the log carries.
        flagged: also export fixes the backend flagged.

    Returns:
        The file written, the scene drawn and the log read (for its skip counters).

    Raises:
        ExportError: unknown format, unreadable log, no origin, or unwritable output.
    """
    if fmt not in WRITERS:
        raise ExportError(f"unknown export format {fmt!r}; one of {', '.join(WRITERS)}")
    suffix, writer = WRITERS[fmt]
    run = read_run(run_path)
    where = run.origin_or(origin)
    scene = build_scene(run, where, flagged=flagged)
    target = Path(out) if out is not None else Path(run_path).with_suffix(suffix)
    return writer(scene, target), scene, run
