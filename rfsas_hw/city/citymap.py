"""The district map of a run: units, coverage per crossing, conflicts defused, nuisance BRAKEs.

Two files from one scorer:

- a PNG (matplotlib, like the project's other plots): the lanes in grey, the
  units as triangles pointing along their boresight, each crossing reached by a
  VRU as a dot coloured by its coverage share (red 0 → green 1; grey: no
  phone-carrying VRU reached it), conflicts as circles (filled green when
  defused, red when not), collisions as black stars, nuisance BRAKEs as orange
  crosses;
- a GeoJSON ``FeatureCollection`` (RFC 7946, written with
  :mod:`rfsas_hw.exports.geojson`'s helpers) with one feature per unit
  (``kind: unit``), crossing (``crossing``, with its counts, share and fix
  error), conflict (``conflict``, with class, advised, defused), collision
  (``collision``) and nuisance BRAKE (``nuisance_brake``), placed on the globe
  through the net's site origin.

Only ids of units, crossings and cars and VRU classes appear: no emitter ids,
no MACs.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rfsas_hw.city.net import NetInfo
from rfsas_hw.city.placement import UnitSite
from rfsas_hw.city.scoring import CityScorer, CitySummary
from rfsas_hw.exports.geojson import feature, position
from rfsas_hw.optional import pyplot
from rfsas_hw.outpaths import save_figure, write_text_atomic

__all__ = ["city_geojson", "write_map"]


def _point(info: NetInfo, x_m: float, y_m: float) -> dict[str, Any]:
    lat, lon, _ = info.origin.to_geodetic(x_m, y_m)
    return {"type": "Point", "coordinates": position(float(lat), float(lon))}


def city_geojson(
    scorer: CityScorer, summary: CitySummary, units: Sequence[UnitSite], info: NetInfo
) -> dict[str, Any]:
    """The run's map as a GeoJSON ``FeatureCollection`` (module docstring)."""
    features = [
        feature(
            _point(info, u.x_m, u.y_m),
            {
                "kind": "unit",
                "id": u.id,
                "junction": u.junction,
                "boresight_deg": round(u.boresight_deg, 2),
                "tile": u.tile,
            },
        )
        for u in units
    ]
    for c in summary.crossings:
        features.append(
            feature(
                _point(info, c.x_m, c.y_m),
                {
                    "kind": "crossing",
                    "id": c.id,
                    "junction": c.junction,
                    "arrivals": c.arrivals,
                    "arrivals_with_phone": c.arrivals_with_phone,
                    "covered": c.covered,
                    "share": c.share,
                    "error_p50_m": c.error_p50_m,
                    "error_mean_m": c.error_mean_m,
                },
            )
        )
    for x, y, cls, advised, defused in scorer.conflict_events:
        features.append(
            feature(
                _point(info, x, y),
                {"kind": "conflict", "vru_class": cls, "advised": advised, "defused": defused},
            )
        )
    for x, y, cls in scorer.collision_events:
        features.append(feature(_point(info, x, y), {"kind": "collision", "vru_class": cls}))
    for x, y, car in scorer.nuisance_events:
        features.append(feature(_point(info, x, y), {"kind": "nuisance_brake", "vehicle": car}))
    return {"type": "FeatureCollection", "features": features}


def write_map(
    scorer: CityScorer,
    units: Sequence[UnitSite],
    info: NetInfo,
    png: str | Path | None,
    geojson: str | Path | None,
) -> list[Path]:
    """Write the run's map as PNG and/or GeoJSON (either may be None); the files written.

    Raises:
        MissingDependencyError: a PNG was asked for and matplotlib is not installed.
        ConfigError: a file cannot be created.
        OutputError: writing failed (disk full); the target is unchanged.
    """
    summary = scorer.summary()
    written: list[Path] = []
    if geojson is not None:
        doc = city_geojson(scorer, summary, units, info)
        p = Path(geojson)
        write_text_atomic(p, json.dumps(doc, allow_nan=False))
        written.append(p)
    if png is not None:
        written.append(_draw(scorer, summary, units, info, Path(png)))
    return written


def _draw(
    scorer: CityScorer,
    summary: CitySummary,
    units: Sequence[UnitSite],
    info: NetInfo,
    path: Path,
) -> Path:
    plt = pyplot()
    from matplotlib.collections import LineCollection

    span_x = info.bounds_m[2] - info.bounds_m[0]
    span_y = info.bounds_m[3] - info.bounds_m[1]
    scale = 12.0 / max(span_x, span_y, 1.0)
    fig, ax = plt.subplots(figsize=(max(span_x * scale, 4.0), max(span_y * scale, 4.0)))
    try:
        lanes = [r.shape for r in info.roads if len(r.shape) > 1]
        ax.add_collection(LineCollection(lanes, colors="0.8", linewidths=0.6, zorder=1))
        cmap = plt.get_cmap("RdYlGn")
        for c in summary.crossings:
            colour = "0.6" if c.share is None else cmap(c.share)
            ax.plot(c.x_m, c.y_m, "o", ms=4, color=colour, zorder=3)
        conflicts = scorer.conflict_events
        for defused in (False, True):
            pts = [(x, y) for x, y, _, _, d in conflicts if d == defused]
            if pts:
                xs, ys = zip(*pts, strict=True)
                ax.scatter(
                    xs,
                    ys,
                    s=18,
                    facecolors="tab:green" if defused else "none",
                    edgecolors="tab:green" if defused else "tab:red",
                    label=f"conflict {'defused' if defused else 'not defused'} ({len(pts)})",
                    zorder=4,
                )
        if scorer.collision_events:
            xs, ys, _ = zip(*scorer.collision_events, strict=True)
            ax.scatter(xs, ys, marker="*", s=60, color="black", label="collision", zorder=5)
        if scorer.nuisance_events:
            xs, ys, _ = zip(*scorer.nuisance_events, strict=True)
            n = len(scorer.nuisance_events)
            ax.scatter(xs, ys, marker="x", s=20, color="tab:orange", label=f"nuisance BRAKE ({n})")
        for u in units:
            a = math.radians(u.boresight_deg)
            ax.plot(u.x_m, u.y_m, marker=(3, 0, -u.boresight_deg), ms=7, color="tab:blue", zorder=6)
            ax.plot(
                [u.x_m, u.x_m + 15 * math.sin(a)],
                [u.y_m, u.y_m + 15 * math.cos(a)],
                color="tab:blue",
                lw=0.8,
                zorder=6,
            )
        ax.plot([], [], marker="^", ls="", color="tab:blue", label=f"units ({len(units)})")
        ax.set_xlim(info.bounds_m[0], info.bounds_m[2])
        ax.set_ylim(info.bounds_m[1], info.bounds_m[3])
        ax.set_aspect("equal")
        ax.set_xlabel("east (m)")
        ax.set_ylabel("north (m)")
        cov = "n/a" if summary.coverage_share is None else f"{summary.coverage_share:.0%}"
        ax.set_title(
            f"{info.path.name}: {summary.conflicts} conflicts, {summary.conflicts_defused} "
            f"defused, {summary.collisions} collisions; crossing coverage {cov}"
        )
        ax.legend(loc="upper right", fontsize="small")
        return save_figure(fig, path, dpi=100)
    finally:
        plt.close(fig)
