"""Cursor-on-Target (CoT 2.0) events of a run, for TAK clients and servers.

Each event is one ``<event version="2.0" …>`` element with a ``<point>``
(WGS-84 degrees, height above the ellipsoid ``hae`` in metres, circular error
``ce`` and linear error ``le`` in metres; 9999999 means unknown) and a
``<detail>``:

- a fix: type ``a-u-G`` (unknown ground object), ``how="m-f"`` (machine,
  fused), uid ``rfsas-<emitter>`` so a TAK map moves one marker per emitter;
  ``ce`` is the one-sigma semi-major axis of the fix's covariance;
  ``<shape><ellipse major minor angle/>`` holds the ``n_sigma`` error
  ellipse's semi-axes (m) and the compass direction of its major axis (°);
- a track point: the same uid and type with ``<track course speed/>``
  (compass degrees, m/s) and the advisory in ``<remarks>``;
- a bearing: type ``u-d-f`` (a drawn line) from the sensor along the azimuth,
  its two ends as ``<link point="lat,lon"/>``;
- a sensor: type ``a-f-G-E-S`` (friendly ground sensor) at its last position.

Every event also has ``<rfsas kind="…" …/>`` with the numbers behind it (the
emitter id is always the keyed hash, never a MAC). A file export writes one
event per line; the live sender (:mod:`rfsas_hw.exports.tak`) sends one per
datagram or, over TCP, one after the other.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from xml.etree import ElementTree as ET

from rfsas_hw.exports.scene import BearingMark, FixMark, SceneStream
from rfsas_hw.exports.shapes import ELLIPSE_SIGMA, Ellipse, ellipse_of, iso_utc
from rfsas_hw.exports.spill import ExternalSort
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.outpaths import write_chunks_atomic
from rfsas_hw.records import Assessment, Fix

UNKNOWN = "9999999"
"""CoT's value for an unknown height or error."""
STALE_S = 60.0
"""Seconds after its time at which a fix or track event goes stale on a TAK map."""
NS = 1_000_000_000

__all__ = [
    "STALE_S",
    "bearing_event",
    "cot_chunks",
    "fix_event",
    "sensor_event",
    "track_event",
    "write_cot",
]


def _event(uid: str, kind: str, t_ns: int, stale_s: float, how: str = "m-f") -> ET.Element:
    return ET.Element(
        "event",
        {
            "version": "2.0",
            "uid": uid,
            "type": kind,
            "how": how,
            "time": iso_utc(t_ns),
            "start": iso_utc(t_ns),
            "stale": iso_utc(t_ns + int(stale_s * NS)),
        },
    )


def _point(event: ET.Element, lat: float, lon: float, hae: float, ce: float | None = None) -> None:
    ET.SubElement(
        event,
        "point",
        {
            "lat": f"{lat:.9f}",
            "lon": f"{lon:.9f}",
            "hae": f"{hae:.3f}",
            "ce": UNKNOWN if ce is None or not math.isfinite(ce) else f"{ce:.3f}",
            "le": UNKNOWN,
        },
    )


def _num(value: float, fmt: str = ".6g") -> str:
    return format(value, fmt) if math.isfinite(value) else "nan"


def fix_event(
    fix: Fix,
    lat_deg: float,
    lon_deg: float,
    hae_m: float,
    ellipse: Ellipse | None = None,
    stale_s: float = STALE_S,
) -> ET.Element:
    """A fix as a CoT event (see the module docstring)."""
    ev = _event(f"rfsas-{fix.emitter}", "a-u-G", fix.t_ns, stale_s)
    one_sigma = ellipse_of(fix.cov_xx_m2, fix.cov_xy_m2, fix.cov_yy_m2, 1.0)
    _point(ev, lat_deg, lon_deg, hae_m, one_sigma.semi_major_m if one_sigma else None)
    detail = ET.SubElement(ev, "detail")
    ET.SubElement(detail, "contact", {"callsign": f"emitter {fix.emitter[:8]}"})
    if ellipse is not None:
        shape = ET.SubElement(detail, "shape")
        ET.SubElement(
            shape,
            "ellipse",
            {
                "major": f"{ellipse.semi_major_m:.3f}",
                "minor": f"{ellipse.semi_minor_m:.3f}",
                "angle": f"{ellipse.orientation_deg:.2f}",
            },
        )
    ET.SubElement(
        detail,
        "rfsas",
        {
            "kind": "fix",
            "emitter": fix.emitter,
            "status": fix.status,
            "sensors": ",".join(fix.sensors),
            "x_m": _num(fix.x_m, ".4f"),
            "y_m": _num(fix.y_m, ".4f"),
            "cov_xx_m2": _num(fix.cov_xx_m2),
            "cov_xy_m2": _num(fix.cov_xy_m2),
            "cov_yy_m2": _num(fix.cov_yy_m2),
            "n_sigma": f"{ellipse.n_sigma:g}" if ellipse is not None else "nan",
        },
    )
    return ev


def track_event(
    emitter: str,
    t_ns: int,
    lat_deg: float,
    lon_deg: float,
    hae_m: float,
    course_deg: float,
    speed_mps: float,
    advisory: str = "",
    stale_s: float = STALE_S,
) -> ET.Element:
    """One point of an emitter's track as a CoT event with ``<track course speed/>``."""
    ev = _event(f"rfsas-{emitter}", "a-u-G", t_ns, stale_s)
    _point(ev, lat_deg, lon_deg, hae_m)
    detail = ET.SubElement(ev, "detail")
    ET.SubElement(detail, "contact", {"callsign": f"emitter {emitter[:8]}"})
    motion = {"course": _num(course_deg, ".2f"), "speed": _num(speed_mps, ".3f")}
    ET.SubElement(detail, "track", motion)
    if advisory:
        ET.SubElement(detail, "remarks").text = f"advisory: {advisory}"
    ET.SubElement(detail, "rfsas", {"kind": "track", "emitter": emitter, "advisory": advisory})
    return ev


def bearing_event(
    sensor_id: str,
    emitter: str,
    t_ns: int,
    start_deg: tuple[float, float],
    end_deg: tuple[float, float],
    hae_m: float,
    azimuth_deg: float,
    sigma_deg: float,
    stale_s: float = STALE_S,
) -> ET.Element:
    """A bearing ray as a drawn CoT line from the sensor (``start_deg``: lat °, lon °)."""
    ev = _event(f"rfsas-bearing-{sensor_id}-{emitter}", "u-d-f", t_ns, stale_s, how="m-g")
    _point(ev, start_deg[0], start_deg[1], hae_m)
    detail = ET.SubElement(ev, "detail")
    for lat, lon in (start_deg, end_deg):
        ET.SubElement(detail, "link", {"point": f"{lat:.9f},{lon:.9f}"})
    ET.SubElement(
        detail,
        "rfsas",
        {
            "kind": "bearing",
            "sensor_id": sensor_id,
            "emitter": emitter,
            "azimuth_deg": _num(azimuth_deg, ".3f"),
            "sigma_deg": _num(sigma_deg, ".3f"),
        },
    )
    return ev


def sensor_event(
    sensor_id: str, t_ns: int, lat_deg: float, lon_deg: float, hae_m: float
) -> ET.Element:
    """A sensor's position as a CoT event."""
    ev = _event(f"rfsas-sensor-{sensor_id}", "a-f-G-E-S", t_ns, STALE_S, how="h-e")
    _point(ev, lat_deg, lon_deg, hae_m)
    detail = ET.SubElement(ev, "detail")
    ET.SubElement(detail, "contact", {"callsign": sensor_id})
    ET.SubElement(detail, "rfsas", {"kind": "sensor", "sensor_id": sensor_id})
    return ev


def fix_event_local(
    fix: Fix, origin: SiteOrigin, n_sigma: float = ELLIPSE_SIGMA, stale_s: float = STALE_S
) -> ET.Element:
    """A fix in local metres as a CoT event, placed through ``origin``."""
    lat, lon, h = origin.to_geodetic(fix.x_m, fix.y_m)
    ell = ellipse_of(fix.cov_xx_m2, fix.cov_xy_m2, fix.cov_yy_m2, n_sigma)
    return fix_event(fix, float(lat), float(lon), float(h), ell, stale_s)


def track_event_local(
    assessment: Assessment, origin: SiteOrigin, stale_s: float = STALE_S
) -> ET.Element:
    """An assessment (a track's current state) as a CoT track event, placed through ``origin``."""
    a = assessment
    lat, lon, h = origin.to_geodetic(a.x_m, a.y_m)
    speed = math.hypot(a.vx_mps, a.vy_mps)
    course = math.degrees(math.atan2(a.vx_mps, a.vy_mps)) % 360.0
    return track_event(
        a.emitter, a.t_ns, float(lat), float(lon), float(h), course, speed, a.advisory, stale_s
    )


def _bearing_event(b: BearingMark, hae_m: float) -> ET.Element:
    bl = b.bearing
    return bearing_event(
        bl.sensor_id,
        bl.emitter,
        bl.t_ns,
        b.start_deg,
        b.end_deg,
        hae_m,
        bl.azimuth_deg,
        bl.sigma_deg,
    )


def cot_chunks(scene: SceneStream) -> Iterator[bytes]:
    """Every sensor, fix, bearing and track point of the scene as CoT event lines, in
    time order (at one time: sensors, fixes, bearings, track points, each in log order).

    The events are put in time order by an
    :class:`~rfsas_hw.exports.spill.ExternalSort`, so a long run is sorted in
    bounded memory.

    Raises:
        OutputError: a temporary file cannot be written.
    """
    hae = scene.origin.height_m
    with ExternalSort() as events:

        def add(t_ns: int, kind: int, event: ET.Element) -> None:
            events.add((t_ns, kind), ET.tostring(event, encoding="utf-8") + b"\n")

        for m in scene.marks():
            if isinstance(m, FixMark):
                add(m.fix.t_ns, 1, fix_event(m.fix, m.lat_deg, m.lon_deg, hae, m.ellipse))
            else:
                add(m.bearing.t_ns, 2, _bearing_event(m, hae))
        for s in scene.sensors():
            add(s.t_ns, 0, sensor_event(s.sensor_id, s.t_ns, s.lat_deg, s.lon_deg, hae))
        for t in scene.tracks():
            for i in range(len(t.t_ns)):
                event = track_event(
                    t.emitter,
                    int(t.t_ns[i]),
                    float(t.lat_deg[i]),
                    float(t.lon_deg[i]),
                    hae,
                    float(t.course_deg[i]),
                    float(t.speed_mps[i]),
                )
                add(int(t.t_ns[i]), 3, event)
        yield from events.sorted()


def write_cot(scene: SceneStream, path: str | Path) -> Path:
    """Write the scene's CoT events to ``path``, one event per line, as it is read.

    Raises:
        ConfigError: the file cannot be created.
        OutputError: writing it failed (disk full); the target is unchanged.
    """
    p = Path(path)
    write_chunks_atomic(p, cot_chunks(scene))
    return p
