"""The district's road net: where it is, what SUMO needs to run on it, and what it holds.

The ``eclipse-sumo`` wheel (the ``city`` extra) ships an OpenStreetMap import
of Berlin-Adlershof, ``tools/game/DRT/osm.net.xml`` under the wheel's
``SUMO_HOME``: :func:`district_net` finds it. Any other SUMO net can be read
the same way (:func:`read_net`).

The wheel's binaries (``sumo``, ``netgenerate``, ``duarouter``) read
projection data from the folder ``PROJ_LIB`` names; :func:`sumo_env` is the
environment that points it (and ``PROJ_DATA``, ``SUMO_HOME``) at the wheel's
own ``data/proj``.

Frames. A SUMO net is a plane: UTM (or another projection) shifted by the
net's offset. The rfsas frame is metres east and north of a site origin on the
WGS-84 ellipsoid (:class:`~rfsas_hw.geo.SiteOrigin`, local ENU). For a
geo-referenced net, :func:`read_net` takes the centre of the net's boundary as
the origin and fits the similarity (rotation, scale, shift) that maps net
coordinates onto that ENU plane, from the net's own projection at a 5 × 5 grid
of points over the net: UTM's grid north differs from true north by the
meridian convergence (about 1.2° in Adlershof) and its scale by up to 0.04 %,
which over 1.5 km would misplace points by tens of metres on the globe. The fit
leaves the largest residual in :attr:`NetInfo.frame_residual_m` (millimetres
for a district). A net without a projection (a generated grid) keeps its axes
and scale: the frame is the net shifted to the boundary's centre, placed at
the origin the caller gives (:data:`DEFAULT_ORIGIN` by default).

Every geometry :class:`NetInfo` holds is in the rfsas frame.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.bridges.sumofiles import check_no_dtd
from rfsas_hw.errors import ConfigError, MissingDependencyError
from rfsas_hw.geo import SiteOrigin

Array = npt.NDArray[np.float64]
Point = tuple[float, float]

DISTRICT_NET = ("tools", "game", "DRT", "osm.net.xml")
"""The Berlin-Adlershof net, relative to the wheel's ``SUMO_HOME``."""
DEFAULT_ORIGIN = SiteOrigin(52.4306, 13.5325)
"""Where a net without a projection is placed on the globe (Adlershof's centre), degrees."""
FIT_GRID = 5
"""Points per axis of the grid the frame similarity is fitted on."""
INSTALL = "pip install 'rfsas-hw[city]'"

__all__ = [
    "DEFAULT_ORIGIN",
    "DISTRICT_NET",
    "Crossing",
    "Junction",
    "NetInfo",
    "Road",
    "district_net",
    "read_net",
    "sumo_binary",
    "sumo_env",
    "sumo_home",
    "sumo_tool",
]


def sumo_home() -> Path:
    """The installed ``eclipse-sumo`` wheel's ``SUMO_HOME``.

    Raises:
        MissingDependencyError: the wheel is not installed (names the extra).
    """
    try:
        import sumo  # the eclipse-sumo wheel's package
    except ImportError as err:
        raise MissingDependencyError(
            f"eclipse-sumo is not installed; install it with: {INSTALL}"
        ) from err
    return Path(str(sumo.SUMO_HOME))


def sumo_env() -> dict[str, str]:
    """This process's environment with ``SUMO_HOME``, ``PROJ_LIB`` and ``PROJ_DATA`` set
    to the wheel's (for SUMO's binaries and tools run as subprocesses).

    Raises:
        MissingDependencyError: the wheel is not installed.
    """
    home = sumo_home()
    proj = str(home / "data" / "proj")
    return {**os.environ, "SUMO_HOME": str(home), "PROJ_LIB": proj, "PROJ_DATA": proj}


def sumo_binary(name: str) -> Path:
    """A binary of the wheel (``sumo``, ``netgenerate``, ``duarouter``, …).

    Raises:
        MissingDependencyError: the wheel is not installed.
        ConfigError: it has no such binary.
    """
    path = sumo_home() / "bin" / name
    if not path.is_file():
        raise ConfigError(f"the eclipse-sumo wheel has no binary {name!r} ({path})")
    return path


def sumo_tool(*parts: str) -> Path:
    """A script of the wheel's ``tools`` folder (``sumo_tool("randomTrips.py")``).

    Raises:
        MissingDependencyError: the wheel is not installed.
        ConfigError: it has no such tool.
    """
    path = sumo_home().joinpath("tools", *parts)
    if not path.is_file():
        raise ConfigError(f"the eclipse-sumo wheel has no tool {'/'.join(parts)} ({path})")
    return path


def district_net() -> Path:
    """The Berlin-Adlershof net shipped in the ``eclipse-sumo`` wheel.

    Raises:
        MissingDependencyError: the wheel is not installed.
        ConfigError: the wheel lacks the net (a build without the tools folder).
    """
    path = sumo_home().joinpath(*DISTRICT_NET)
    if not path.is_file():
        raise ConfigError(f"the eclipse-sumo wheel has no district net at {path}")
    return path


@dataclass(frozen=True, slots=True)
class Junction:
    """A junction of the net, rfsas frame."""

    id: str
    """SUMO's junction id."""
    x_m: float
    """Centre, metres east of the origin."""
    y_m: float
    """Centre, metres north of the origin."""
    shape: tuple[Point, ...]
    """Outline polygon (east, north) metres; may be empty for a junction without one."""
    tls: tuple[str, ...]
    """Ids of the traffic-light programs that control it (empty: not signalised)."""


@dataclass(frozen=True, slots=True)
class Crossing:
    """A pedestrian crossing: a straight walk from one kerb to the other, rfsas frame."""

    id: str
    """SUMO's crossing edge id (``:junction_cN``)."""
    junction: str
    """The junction it belongs to."""
    kerb_a: Point
    """One end (east, north), metres."""
    kerb_b: Point
    """The other end (east, north), metres."""
    width_m: float
    """Width of the crossing, metres."""
    signalised: bool
    """Whether a traffic light controls it."""

    @property
    def length_m(self) -> float:
        """Kerb to kerb, metres."""
        return math.dist(self.kerb_a, self.kerb_b)


@dataclass(frozen=True, slots=True)
class Road:
    """One lane of a normal (not internal) edge, as drawn: a polyline with a width."""

    edge: str
    """SUMO's edge id."""
    shape: tuple[Point, ...]
    """Centre line (east, north), metres."""
    width_m: float
    """Lane width, metres."""
    pedestrian_only: bool
    """Whether only pedestrians may use it (a sidewalk or footpath)."""
    cars: bool
    """Whether passenger cars may use it."""


@dataclass(frozen=True)
class NetInfo:
    """What the district model needs of a SUMO net, in the rfsas frame (module docstring)."""

    path: Path
    """The net file."""
    origin: SiteOrigin
    """The geodetic point the frame's (0, 0) stands for."""
    georeferenced: bool
    """Whether the net has a projection (else the origin is only a placement)."""
    net_centre: Point
    """Net coordinates of the frame's origin, metres."""
    rotation_deg: float
    """Angle from net axes to the frame's axes, degrees counter-clockwise (the frame's
    east is the net's x turned by this)."""
    scale: float
    """Frame metres per net unit."""
    frame_residual_m: float
    """Largest misfit of the frame similarity on its fit grid, metres (0 without projection)."""
    bounds_m: tuple[float, float, float, float]
    """(x_min, y_min, x_max, y_max) of the net's boundary in the frame, metres."""
    junctions: tuple[Junction, ...]
    """Every non-internal junction."""
    crossings: tuple[Crossing, ...]
    """Every pedestrian crossing."""
    roads: tuple[Road, ...]
    """Every lane of every normal edge."""

    @property
    def tls_junctions(self) -> tuple[Junction, ...]:
        """The junctions a traffic light controls."""
        return tuple(j for j in self.junctions if j.tls)

    def to_frame(self, x_net: npt.ArrayLike, y_net: npt.ArrayLike) -> tuple[Array, Array]:
        """Net coordinates → rfsas frame (east, north), metres; arrays broadcast."""
        x = np.asarray(x_net, dtype=np.float64) - self.net_centre[0]
        y = np.asarray(y_net, dtype=np.float64) - self.net_centre[1]
        a = math.radians(self.rotation_deg)
        c, s = self.scale * math.cos(a), self.scale * math.sin(a)
        return c * x - s * y, s * x + c * y

    def to_net(self, east_m: npt.ArrayLike, north_m: npt.ArrayLike) -> tuple[Array, Array]:
        """rfsas frame (east, north) metres → net coordinates; the inverse of :meth:`to_frame`."""
        e = np.asarray(east_m, dtype=np.float64)
        n = np.asarray(north_m, dtype=np.float64)
        a = math.radians(self.rotation_deg)
        c, s = math.cos(a) / self.scale, math.sin(a) / self.scale
        return c * e + s * n + self.net_centre[0], -s * e + c * n + self.net_centre[1]

    def heading_to_frame(self, angle_deg: npt.ArrayLike) -> Array:
        """A SUMO angle (compass degrees in the net's axes) → compass degrees in the frame."""
        return np.asarray((np.asarray(angle_deg, dtype=np.float64) - self.rotation_deg) % 360.0)

    def points_to_frame(self, shape: Sequence[Sequence[float]]) -> tuple[Point, ...]:
        """A SUMO shape (net coordinates) as a tuple of frame points, metres."""
        if not shape:
            return ()
        arr = np.asarray([(p[0], p[1]) for p in shape], dtype=np.float64)
        e, n = self.to_frame(arr[:, 0], arr[:, 1])
        return tuple((float(a), float(b)) for a, b in zip(e, n, strict=True))


def _sumolib() -> Any:
    sumo_home()  # sets SUMO_HOME and PROJ_LIB for sumolib's projection
    try:
        import sumolib
    except ImportError as err:
        raise MissingDependencyError(
            f"sumolib is not installed; install it with: {INSTALL}"
        ) from err
    return sumolib


def _fit_similarity(net_xy: Array, enu: Array) -> tuple[float, float, float]:
    """Least-squares similarity ``enu ≈ k·R(θ)·net_xy`` (both centred on the same point):
    (θ degrees, k, largest residual metres)."""
    z_net = net_xy[:, 0] + 1j * net_xy[:, 1]
    z_enu = enu[:, 0] + 1j * enu[:, 1]
    a = complex(np.vdot(z_net, z_enu) / np.vdot(z_net, z_net))
    residual = float(np.max(np.abs(a * z_net - z_enu)))
    return math.degrees(math.atan2(a.imag, a.real)), abs(a), residual


def read_net(path: str | Path, origin: SiteOrigin | None = None) -> NetInfo:
    """Read a SUMO net into a :class:`NetInfo` (rfsas frame, see the module docstring).

    Args:
        path: the ``.net.xml`` file.
        origin: where to place a net without a projection (default
            :data:`DEFAULT_ORIGIN`); ignored for a geo-referenced net.

    Raises:
        MissingDependencyError: eclipse-sumo or sumolib is not installed, or pyproj for a
            geo-referenced net.
        ConfigError: the file is missing, has a DTD, or is not a SUMO net.
    """
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{p}: no such net file")
    check_no_dtd(p)
    sumolib = _sumolib()
    try:
        net = sumolib.net.readNet(str(p), withInternal=True, withPedestrianConnections=True)
    except Exception as err:  # sumolib raises plain exceptions of many kinds on bad XML
        raise ConfigError(f"{p}: not a SUMO net: {err}") from err
    try:
        x0, y0, x1, y1 = (float(v) for v in net.getBoundary())
    except (KeyError, ValueError) as err:  # no <location convBoundary=…>: not a net file
        raise ConfigError(
            f"{p}: not a SUMO net: it has no <location> with a convBoundary (is it a "
            "polygon, route or other additional file?)"
        ) from err
    if not (x1 > x0 and y1 > y0):
        raise ConfigError(f"{p}: the net has an empty boundary")
    centre = ((x0 + x1) / 2, (y0 + y1) / 2)
    rotation, scale, residual = 0.0, 1.0, 0.0
    georef = bool(net.hasGeoProj())
    if georef:
        try:
            import pyproj  # noqa: F401  (sumolib projects with it)
        except ImportError as err:
            raise MissingDependencyError(
                f"{p} is geo-referenced and pyproj is not installed; install it with: {INSTALL}"
            ) from err
        lon, lat = net.convertXY2LonLat(*centre)
        site = SiteOrigin(float(lat), float(lon))
        gx, gy = np.meshgrid(np.linspace(x0, x1, FIT_GRID), np.linspace(y0, y1, FIT_GRID))
        grid = np.column_stack([gx.ravel(), gy.ravel()])
        lonlat = np.asarray([net.convertXY2LonLat(float(x), float(y)) for x, y in grid])
        e, n, _ = site.to_local(lonlat[:, 1], lonlat[:, 0])
        rotation, scale, residual = _fit_similarity(
            grid - np.asarray(centre), np.column_stack([e, n])
        )
    else:
        site = origin or DEFAULT_ORIGIN
    # the frame first (no geometry yet): its transform converts the geometry below
    frame = NetInfo(
        path=p,
        origin=site,
        georeferenced=georef,
        net_centre=centre,
        rotation_deg=rotation,
        scale=scale,
        frame_residual_m=residual,
        bounds_m=(0.0, 0.0, 0.0, 0.0),
        junctions=(),
        crossings=(),
        roads=(),
    )
    corners = frame.points_to_frame([(x0, y0), (x1, y0), (x1, y1), (x0, y1)])
    xs, ys = [c[0] for c in corners], [c[1] for c in corners]
    tls_of: dict[str, set[str]] = {}
    for tl in net.getTrafficLights():
        for conn in tl.getConnections():
            node = conn[0].getEdge().getToNode()
            tls_of.setdefault(node.getID(), set()).add(tl.getID())
    junctions = []
    for node in net.getNodes():
        if node.getType() == "internal":
            continue
        cx, cy = node.getCoord()[:2]
        (jx, jy), *_ = frame.points_to_frame([(cx, cy)])
        signalised = tls_of.get(node.getID(), set())
        if node.getType().startswith("traffic_light") and not signalised:
            signalised = {node.getID()}
        junctions.append(
            Junction(
                id=node.getID(),
                x_m=jx,
                y_m=jy,
                shape=frame.points_to_frame(node.getShape() or []),
                tls=tuple(sorted(signalised)),
            )
        )
    tls_nodes = {j.id for j in junctions if j.tls}
    crossings, roads = [], []
    for edge in net.getEdges(withInternal=True):
        function = edge.getFunction()
        if function == "crossing":
            lane = edge.getLanes()[0]
            shape = frame.points_to_frame(lane.getShape())
            node = edge.getFromNode() or edge.getToNode()
            jid = node.getID() if node is not None else edge.getID().lstrip(":").rsplit("_", 1)[0]
            crossings.append(
                Crossing(
                    id=edge.getID(),
                    junction=jid,
                    kerb_a=shape[0],
                    kerb_b=shape[-1],
                    width_m=float(lane.getWidth()),
                    signalised=jid in tls_nodes,
                )
            )
        elif function == "":
            for lane in edge.getLanes():
                allowed = lane.getPermissions()
                roads.append(
                    Road(
                        edge=edge.getID(),
                        shape=frame.points_to_frame(lane.getShape()),
                        width_m=float(lane.getWidth()),
                        pedestrian_only=set(allowed) == {"pedestrian"},
                        cars="passenger" in allowed,
                    )
                )
    return replace(
        frame,
        bounds_m=(min(xs), min(ys), max(xs), max(ys)),
        junctions=tuple(junctions),
        crossings=tuple(sorted(crossings, key=lambda c: c.id)),
        roads=tuple(roads),
    )
