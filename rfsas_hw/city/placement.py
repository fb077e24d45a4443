"""Where the district's roadside units stand, and which buildings block their view.

Units. By default every signalised junction gets two units on opposite
corners, each facing the junction's centre. A "signalised junction" is one
traffic-light program: SUMO joins the nodes of a wide crossroads (a dual
carriageway meets a road) into one program, and those nodes are one place on
the street, so they get one pair. The pair stands on the diagonal through the
junction's centre that bisects its roads: the roads' axis is the dominant
direction of the junction outlines' edges (edge directions averaged modulo
90°, weighted by length), the corners lie at 45° and 225° from it, ``setback_m``
beyond the outline's farthest vertex. A YAML file overrides it::

    junctions: [gneJ7, cluster_1_2]   # which programs get units (default: all)
    per_junction: 2                   # 1 or 2
    setback_m: 4.0
    units:                            # units of your own (rfsas frame, metres)
      - {id: rsu-park, x_m: 120.0, y_m: -40.5, boresight_deg: 270.0}
    replace: false                    # true: only the units listed above

Buildings. From a SUMO polygon file when given (every polygon of type
``building``, as its axis-aligned bounding box, since the twin's buildings are
axis-aligned rectangles); otherwise derived from the net's city blocks: the
net is rasterised at :data:`RASTER_M`; every lane (sidewalks included) and
every junction's outline is street, and so is everything within half the
widest lane plus ``setback_m`` of it; each connected area of what is left that
does not touch the net's edge is a city block. A block's interior is covered
by square cells of ``cell_m`` that lie wholly inside it, and the cells of a row
are merged into one rectangle per run. Only buildings within ``near_m`` of a
unit are kept, since only those can stand between a unit and a phone it hears.
"""

from __future__ import annotations

import hashlib
import math
import xml.parsers.expat
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from rfsas_hw.bridges.sumo import BUILDING_TYPES
from rfsas_hw.bridges.sumofiles import check_no_dtd
from rfsas_hw.city.net import Junction, NetInfo
from rfsas_hw.config import from_mapping, read_yaml
from rfsas_hw.errors import ConfigError
from rfsas_hw.link.message import check_sender_id
from rfsas_hw.link.topics import quadkey
from rfsas_hw.twin.scenario import BuildingSpec

RASTER_M = 2.0
"""Cell of the raster city blocks are found on, metres."""
BUILDING_LOSS_DB = 20.0
"""Extra loss through a derived building, dB (the twin's default)."""
OFF_NET_M = 50.0
"""How far beyond the net's boundary a unit of the user's own may stand, metres (chosen:
a unit farther out hears next to nothing of the district, so it is taken for a typo)."""

__all__ = [
    "BuildingOptions",
    "PlacementConfig",
    "UnitOverride",
    "UnitSite",
    "buildings",
    "load_placement",
    "place_units",
    "placed_units",
]


@dataclass(frozen=True, slots=True)
class UnitSite:
    """One roadside unit of the district (rfsas frame)."""

    id: str
    """Unit id (a sensor id: letters, digits, ``._-``, at most 32)."""
    x_m: float
    """Metres east of the site origin."""
    y_m: float
    """Metres north of the site origin."""
    boresight_deg: float
    """Compass direction the unit faces, degrees clockwise from north."""
    junction: str
    """The traffic-light program (or, for a unit of the YAML, ``""``) it watches."""
    tile: str
    """Zoom-16 quadkey of its position: the tile its bearings are published under."""


@dataclass(frozen=True)
class UnitOverride:
    """A unit given in the placement YAML."""

    id: str
    x_m: float
    y_m: float
    boresight_deg: float


@dataclass(frozen=True)
class PlacementConfig:
    """Which junctions get units and where (module docstring)."""

    junctions: tuple[str, ...] | None = None
    """Traffic-light program ids that get units (None: every one)."""
    per_junction: int = 2
    """Units per junction: 2 on opposite corners, or 1 on the first corner."""
    setback_m: float = 4.0
    """Distance beyond the junction outline, metres."""
    units: tuple[UnitOverride, ...] = ()
    """Units of the user's own."""
    replace: bool = False
    """Only the user's units, none placed automatically."""

    def __post_init__(self) -> None:
        if self.per_junction not in (1, 2):
            raise ConfigError(f"per_junction must be 1 or 2, got {self.per_junction}")
        if not (math.isfinite(self.setback_m) and self.setback_m >= 0):
            raise ConfigError(f"setback_m must be a number >= 0, got {self.setback_m}")


def load_placement(path: str | Path) -> PlacementConfig:
    """Read a placement YAML (module docstring).

    Raises:
        ConfigError: unreadable file, unknown key, wrong type or range (the message
            names the file and key).
    """
    data = read_yaml(path) or {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping")
    try:
        return from_mapping(PlacementConfig, data, str(path))
    except ConfigError as err:
        if str(err).startswith(f"{path}:"):
            raise
        raise ConfigError(f"{path}: {err}") from err  # a range check of PlacementConfig


def placed_units(info: NetInfo, path: str | Path | None = None) -> list[UnitSite]:
    """The units of the placement file ``path`` on the net (None: the default placement,
    two units at every traffic light); see :func:`place_units`.

    Raises:
        ConfigError: as :func:`load_placement` and :func:`place_units`, naming the file.
    """
    if path is None:
        return place_units(info)
    cfg = load_placement(path)
    try:
        return place_units(info, cfg)
    except ConfigError as err:
        raise ConfigError(f"{path}: {err}") from err


def _axis_deg(shapes: Sequence[Sequence[tuple[float, float]]]) -> float:
    """The dominant direction (math angle, degrees in [0, 90)) of the outlines' edges."""
    acc = 0j
    for shape in shapes:
        pts = np.asarray(shape, dtype=np.float64)
        if len(pts) < 2:
            continue
        d = np.diff(np.vstack([pts, pts[:1]]), axis=0)
        length = np.hypot(d[:, 0], d[:, 1])
        acc += complex(np.sum(length * np.exp(4j * np.arctan2(d[:, 1], d[:, 0]))))
    if abs(acc) == 0:
        return 0.0
    return math.degrees(np.angle(acc) / 4) % 90.0


def _site(info: NetInfo, uid: str, x: float, y: float, boresight: float, junction: str) -> UnitSite:
    lat, lon, _ = info.origin.to_geodetic(x, y)
    return UnitSite(uid, x, y, boresight % 360.0, junction, quadkey(float(lat), float(lon)))


def _pair(info: NetInfo, tls: str, members: list[Junction], cfg: PlacementConfig) -> list[UnitSite]:
    cx = float(np.mean([j.x_m for j in members]))
    cy = float(np.mean([j.y_m for j in members]))
    shapes = [j.shape for j in members if j.shape]
    verts = [p for s in shapes for p in s] or [(j.x_m, j.y_m) for j in members]
    reach = max(math.dist((cx, cy), p) for p in verts) + cfg.setback_m
    axis = _axis_deg(shapes)
    out = []
    for k, turn in enumerate((45.0, 225.0)[: cfg.per_junction]):
        a = math.radians(axis + turn)
        x, y = cx + reach * math.cos(a), cy + reach * math.sin(a)
        facing = math.degrees(math.atan2(cx - x, cy - y))  # compass bearing to the centre
        out.append(_site(info, f"rsu-{_slug(tls)}-{k}", x, y, facing, tls))
    return out


def _slug(ident: str) -> str:
    """A sensor-id-safe form of a SUMO id (SUMO ids may hold any character)."""
    keep = "".join(c if c.isalnum() or c in "._-" else "_" for c in ident)
    if len(keep) <= 22:
        return keep
    return f"{keep[:14]}-{hashlib.sha256(ident.encode()).hexdigest()[:7]}"


def place_units(info: NetInfo, cfg: PlacementConfig | None = None) -> list[UnitSite]:
    """The district's roadside units (module docstring), sorted by id.

    Raises:
        ConfigError: a junction named in ``cfg`` is not a traffic-light program of the
            net, a unit id is invalid or used twice, a unit of the user's own stands more
            than :data:`OFF_NET_M` beyond the net's boundary, or no unit results.
    """
    cfg = cfg or PlacementConfig()
    by_tls: dict[str, list[Junction]] = {}
    for j in info.tls_junctions:
        for t in j.tls:
            by_tls.setdefault(t, []).append(j)
    chosen = sorted(by_tls) if cfg.junctions is None else list(cfg.junctions)
    units: list[UnitSite] = []
    if not cfg.replace:
        for tls in chosen:
            if tls not in by_tls:
                known = ", ".join(sorted(by_tls)[:8])
                raise ConfigError(
                    f"placement: junctions: {tls!r} is not a traffic-light program of "
                    f"{info.path.name} (some known: {known})"
                )
            units.extend(_pair(info, tls, by_tls[tls], cfg))
    x0, y0, x1, y1 = info.bounds_m
    for u in cfg.units:
        try:
            check_sender_id(u.id)
        except Exception as err:
            raise ConfigError(f"placement: units: {err}") from err
        if not (
            x0 - OFF_NET_M <= u.x_m <= x1 + OFF_NET_M and y0 - OFF_NET_M <= u.y_m <= y1 + OFF_NET_M
        ):
            raise ConfigError(
                f"placement: units: {u.id!r} at x_m {u.x_m:g}, y_m {u.y_m:g} is off the net: "
                f"{info.path.name} spans x {x0:.0f} to {x1:.0f} m and y {y0:.0f} to {y1:.0f} m "
                f"(rfsas frame: metres east and north), and a unit may stand at "
                f"most {OFF_NET_M:g} m beyond that"
            )
        units.append(_site(info, u.id, u.x_m, u.y_m, u.boresight_deg, ""))
    ids = [u.id for u in units]
    dup = {i for i in ids if ids.count(i) > 1}
    if dup:
        raise ConfigError(f"placement: unit id(s) used twice: {', '.join(sorted(dup))}")
    if not units:
        if cfg.replace:
            why = "replace is true and units lists none"
        elif not by_tls:
            why = (
                f"{info.path.name} has no traffic light to place them at; list units of "
                "your own under units: in a placement file"
            )
        else:
            why = "junctions lists none"
        raise ConfigError(f"placement: no units: {why}")
    return sorted(units, key=lambda u: u.id)


@dataclass(frozen=True)
class BuildingOptions:
    """How buildings are derived from the net's blocks (module docstring)."""

    setback_m: float = 3.0
    """Clearance between a lane's edge and a building, metres."""
    cell_m: float = 16.0
    """Side of the square cells a block's interior is covered with, metres."""
    near_m: float = 200.0
    """Only buildings within this distance of a unit are kept, metres."""
    extra: list[BuildingSpec] = field(default_factory=list)
    """Buildings added as they are."""


def _shape_point(text: str) -> tuple[float, float] | None:
    """``x,y`` (or ``x,y,z``) of a SUMO shape as finite numbers; None if it is not one."""
    parts = text.split(",")
    if len(parts) not in (2, 3):
        return None
    try:
        x, y = float(parts[0]), float(parts[1])
    except ValueError:
        return None
    return (x, y) if math.isfinite(x) and math.isfinite(y) else None


def _polygon_buildings(path: Path) -> list[tuple[str, list[tuple[float, float]]]]:
    """``(id, shape)`` of every building polygon of a SUMO polygon file (net coordinates)."""
    check_no_dtd(path)
    found: list[tuple[str, list[tuple[float, float]]]] = []
    parser = xml.parsers.expat.ParserCreate()

    def start(tag: str, attrs: dict[str, str]) -> None:
        if tag != "poly" or attrs.get("type", "") not in BUILDING_TYPES:
            return
        pts = [_shape_point(p) for p in attrs.get("shape", "").split()]
        if not pts or None in pts:
            raise ConfigError(
                f"{path}: line {parser.CurrentLineNumber}: poly {attrs.get('id', '?')!r}: "
                f"bad shape {attrs.get('shape', '')!r} (expected points x,y in metres, "
                "separated by spaces)"
            )
        found.append((attrs.get("id", ""), [p for p in pts if p is not None]))

    parser.StartElementHandler = start
    try:
        with path.open("rb") as fh:
            parser.ParseFile(fh)
    except OSError as err:
        raise ConfigError(f"{path}: cannot read: {err.strerror or err}") from err
    except xml.parsers.expat.ExpatError as err:
        raise ConfigError(f"{path}: not a SUMO polygon file: {err}") from err
    return found


def _near(b: BuildingSpec, units: Sequence[UnitSite], near_m: float) -> bool:
    for u in units:
        dx = max(b.x_min_m - u.x_m, 0.0, u.x_m - b.x_max_m)
        dy = max(b.y_min_m - u.y_m, 0.0, u.y_m - b.y_max_m)
        if dx * dx + dy * dy <= near_m * near_m:
            return True
    return False


def _fill(
    raster: npt.NDArray[np.bool_], shape: Sequence[tuple[float, float]], corner: tuple[float, float]
) -> None:
    """Mark the cells of ``raster`` (origin ``corner``, :data:`RASTER_M` cells) whose
    centres lie inside polygon ``shape`` (even-odd rule)."""
    if len(shape) < 3:
        return
    poly = np.asarray(shape, dtype=np.float64)
    lo = np.floor((poly.min(axis=0) - corner) / RASTER_M).astype(int)
    hi = np.ceil((poly.max(axis=0) - corner) / RASTER_M).astype(int)
    lo = np.clip(lo, 0, [raster.shape[1] - 1, raster.shape[0] - 1])
    hi = np.clip(hi, 0, [raster.shape[1] - 1, raster.shape[0] - 1])
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1))
    px = corner[0] + (gx + 0.5) * RASTER_M
    py = corner[1] + (gy + 0.5) * RASTER_M
    inside = np.zeros(px.shape, dtype=bool)
    for (ax, ay), (bx, by) in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        if ay == by:
            continue
        crosses = (ay > py) != (by > py)
        x_at = ax + (py - ay) * (bx - ax) / (by - ay)
        inside ^= crosses & (px < x_at)
    raster[gy[inside], gx[inside]] = True


def _block_buildings(info: NetInfo, opts: BuildingOptions) -> list[BuildingSpec]:
    x0, y0, x1, y1 = info.bounds_m
    nx, ny = math.ceil((x1 - x0) / RASTER_M) + 1, math.ceil((y1 - y0) / RASTER_M) + 1
    road = np.zeros((ny, nx), dtype=bool)
    for r in info.roads:
        pts = np.asarray(r.shape, dtype=np.float64)
        if len(pts) < 2:
            continue
        # sample each lane every half cell and mark the cell under each sample
        seg = np.diff(pts, axis=0)
        steps = np.maximum(np.ceil(np.hypot(seg[:, 0], seg[:, 1]) / (RASTER_M / 2)), 1)
        samples = np.vstack(
            [
                pts[i] + np.outer(np.linspace(0.0, 1.0, int(n) + 1), seg[i])
                for i, n in enumerate(steps)
            ]
        )
        ix = np.clip(((samples[:, 0] - x0) / RASTER_M).astype(int), 0, nx - 1)
        iy = np.clip(((samples[:, 1] - y0) / RASTER_M).astype(int), 0, ny - 1)
        road[iy, ix] = True
    for j in info.junctions:
        _fill(road, j.shape, (x0, y0))
    half_widths = max((r.width_m for r in info.roads), default=3.2) / 2
    clearance = ndimage.distance_transform_edt(~road) * RASTER_M
    free = clearance > half_widths + opts.setback_m
    labels, _ = ndimage.label(free)
    edge = set(np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])))
    k = max(round(opts.cell_m / RASTER_M), 1)
    out: list[BuildingSpec] = []
    for i, sl in enumerate(ndimage.find_objects(labels), start=1):
        if sl is None or i in edge:
            continue
        block = labels[sl] == i
        h, w = block.shape[0] // k, block.shape[1] // k
        if h == 0 or w == 0:
            continue
        cells = block[: h * k, : w * k].reshape(h, k, w, k).all(axis=(1, 3))
        for row in range(h):
            padded = np.concatenate([[False], cells[row], [False]])
            change = np.flatnonzero(np.diff(padded.astype(np.int8)))
            for start, stop in zip(change[::2], change[1::2], strict=True):
                bx0 = float(x0 + (sl[1].start + start * k) * RASTER_M)
                by0 = float(y0 + (sl[0].start + row * k) * RASTER_M)
                out.append(
                    BuildingSpec(
                        x_min_m=bx0,
                        x_max_m=bx0 + float(stop - start) * k * RASTER_M,
                        y_min_m=by0,
                        y_max_m=by0 + k * RASTER_M,
                        name=f"block{i}-{row}-{start}",
                        loss_db=BUILDING_LOSS_DB,
                    )
                )
    return out


def buildings(
    info: NetInfo,
    units: Sequence[UnitSite],
    polygons: str | Path | None = None,
    opts: BuildingOptions | None = None,
) -> list[BuildingSpec]:
    """The buildings near the units, rfsas frame (module docstring).

    Args:
        info: the net.
        units: the units; buildings farther than ``opts.near_m`` from all of them are left out.
        polygons: a SUMO polygon file (net coordinates); None: derive from city blocks.
        opts: how to derive them.

    Raises:
        ConfigError: the polygon file is missing, unreadable, has a DTD or a bad shape.
    """
    opts = opts or BuildingOptions()
    found: list[BuildingSpec] = []
    if polygons is not None:
        p = Path(polygons)
        if not p.is_file():
            raise ConfigError(f"{p}: no such polygon file")
        for pid, shape in _polygon_buildings(p):
            pts = info.points_to_frame(shape)
            xs, ys = [q[0] for q in pts], [q[1] for q in pts]
            if max(xs) > min(xs) and max(ys) > min(ys):
                found.append(
                    BuildingSpec(min(xs), max(xs), min(ys), max(ys), pid, BUILDING_LOSS_DB)
                )
    else:
        found = _block_buildings(info, opts)
    return [b for b in found if _near(b, units, opts.near_m)] + list(opts.extra)
