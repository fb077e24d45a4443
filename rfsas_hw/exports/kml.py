"""KML 2.2 of a run: for Google Earth and the GIS tools that read KML.

One ``Document`` with four ``Folder`` elements, each ``Placemark`` carrying a
``TimeStamp`` (or a ``gx:Track``'s ``when`` list) so the time slider plays the
run back:

- ``Sensors``: a ``Point`` per sensor;
- ``Fixes``: a ``MultiGeometry`` of the fix's ``Point`` and its error-ellipse
  ``Polygon``; ``ExtendedData`` holds the emitter id, status, covariance and
  ellipse axes;
- ``Bearings``: a ``LineString`` from the sensor along the azimuth;
- ``Tracks``: a ``gx:Track`` per emitter (``when`` + ``gx:coord`` pairs).

Coordinates are ``lon,lat,0`` in WGS-84 degrees with 8 decimals, clamped to
the ground. The file is written as the run log is read (see :func:`kml_chunks`).
"""

from __future__ import annotations

import io
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any
from xml.etree import ElementTree as ET

from rfsas_hw.exports.scene import BearingMark, FixMark, SceneStream, SensorMark, TrackPath
from rfsas_hw.exports.shapes import iso_utc
from rfsas_hw.exports.spill import Spool
from rfsas_hw.outpaths import write_chunks_atomic

KML_NS = "http://www.opengis.net/kml/2.2"
GX_NS = "http://www.google.com/kml/ext/2.2"
DECIMALS = 8

__all__ = ["GX_NS", "KML_NS", "kml_chunks", "write_kml"]

STYLES = {
    "sensor": ("ff000000", "ff000000"),
    "fix": ("ff0000dd", "400000dd"),
    "bearing": ("a0ff7700", "00000000"),
    "track": ("ffdd00aa", "00000000"),
}
"""Line and fill colours per style, KML ``aabbggrr``."""


FOLDERS = ("Sensors", "Fixes", "Bearings", "Tracks")
"""The document's folders, in order."""
INDENT = " "
"""One level of indentation."""
_END_FOLDER = b"\n" + INDENT.encode() * 2 + b"</Folder>"
_PLACEMARK = b"\n" + INDENT.encode() * 3
"""What goes before each ``Placemark`` of a folder (level 3 of the document)."""


def _sub(parent: ET.Element, tag: str, text: str | None = None, **attrib: str) -> ET.Element:
    # tags are written as in the document: KML is its default namespace, gx: a prefix
    el = ET.SubElement(parent, tag, attrib)
    if text is not None:
        el.text = text
    return el


def _coord(lat: float, lon: float) -> str:
    return f"{lon:.{DECIMALS}f},{lat:.{DECIMALS}f},0"


def _extended(parent: ET.Element, data: dict[str, Any]) -> None:
    ext = _sub(parent, "ExtendedData")
    for key, value in data.items():
        d = _sub(ext, "Data", name=key)
        _sub(d, "value", str(value))


def _placemark(name: str, style: str, t_ns: int | None) -> ET.Element:
    pm = ET.Element("Placemark")
    _sub(pm, "name", name)
    _sub(pm, "styleUrl", f"#{style}")
    if t_ns is not None:
        ts = _sub(pm, "TimeStamp")
        _sub(ts, "when", iso_utc(t_ns))
    return pm


def _sensor(s: SensorMark) -> ET.Element:
    pm = _placemark(s.sensor_id, "sensor", s.t_ns)
    _sub(_sub(pm, "Point"), "coordinates", _coord(s.lat_deg, s.lon_deg))
    return pm


def _fix(m: FixMark) -> ET.Element:
    f = m.fix
    pm = _placemark(f.emitter, "fix", f.t_ns)
    data: dict[str, Any] = {
        "kind": "fix",
        "emitter": f.emitter,
        "status": f.status,
        "sensors": ",".join(f.sensors),
        "cov_xx_m2": f"{f.cov_xx_m2:.6g}",
        "cov_xy_m2": f"{f.cov_xy_m2:.6g}",
        "cov_yy_m2": f"{f.cov_yy_m2:.6g}",
    }
    if m.ellipse is not None:
        data.update(
            n_sigma=f"{m.ellipse.n_sigma:g}",
            semi_major_m=f"{m.ellipse.semi_major_m:.3f}",
            semi_minor_m=f"{m.ellipse.semi_minor_m:.3f}",
            orientation_deg=f"{m.ellipse.orientation_deg:.2f}",
        )
    _extended(pm, data)
    geoms = _sub(pm, "MultiGeometry")
    _sub(_sub(geoms, "Point"), "coordinates", _coord(m.lat_deg, m.lon_deg))
    if m.ring_deg is not None:
        poly = _sub(geoms, "Polygon")
        _sub(poly, "tessellate", "1")
        ring = _sub(_sub(poly, "outerBoundaryIs"), "LinearRing")
        _sub(ring, "coordinates", " ".join(_coord(lat, lon) for lat, lon in m.ring_deg))
    return pm


def _bearing(b: BearingMark) -> ET.Element:
    pm = _placemark(f"{b.bearing.sensor_id} → {b.bearing.emitter}", "bearing", None)
    ts = _sub(pm, "TimeStamp")
    _sub(ts, "when", iso_utc(b.bearing.t_ns))
    _extended(
        pm,
        {
            "kind": "bearing",
            "sensor_id": b.bearing.sensor_id,
            "emitter": b.bearing.emitter,
            "azimuth_deg": f"{b.bearing.azimuth_deg:.3f}",
            "sigma_deg": f"{b.bearing.sigma_deg:.3f}",
        },
    )
    ray = _sub(pm, "LineString")
    _sub(ray, "tessellate", "1")
    _sub(ray, "coordinates", f"{_coord(*b.start_deg)} {_coord(*b.end_deg)}")
    return pm


def _track(t: TrackPath) -> ET.Element:
    pm = _placemark(f"track {t.emitter}", "track", None)
    _extended(pm, {"kind": "track", "emitter": t.emitter})
    track = _sub(pm, "gx:Track")
    for v in t.t_ns:
        _sub(track, "when", iso_utc(int(v)))
    for lat, lon in zip(t.lat_deg, t.lon_deg, strict=True):
        _sub(track, "gx:coord", f"{lon:.{DECIMALS}f} {lat:.{DECIMALS}f} 0")
    return pm


def _text(pm: ET.Element) -> bytes:
    """A placemark as it reads inside its folder, on a new line."""
    ET.indent(pm, space=INDENT, level=3)
    text: bytes = ET.tostring(pm, encoding="utf-8")
    return _PLACEMARK + text


def _skeleton(name: str) -> list[bytes]:
    """The document without placemarks, cut where each folder's placemarks go."""
    root = ET.Element("kml", {"xmlns": KML_NS, "xmlns:gx": GX_NS})
    doc = _sub(root, "Document")
    _sub(doc, "name", name)
    for style, (line, fill) in STYLES.items():
        st = _sub(doc, "Style", id=style)
        ls = _sub(st, "LineStyle")
        _sub(ls, "color", line)
        _sub(ls, "width", "2")
        ps = _sub(st, "PolyStyle")
        _sub(ps, "color", fill)
    for folder in FOLDERS:
        _sub(_sub(doc, "Folder"), "name", folder)
    tree = ET.ElementTree(root)
    ET.indent(tree, space=INDENT)
    document = io.BytesIO()
    tree.write(document, encoding="utf-8", xml_declaration=True)
    # the name is escaped ("<" as "&lt;"), so only the folders' ends hold the cut
    return document.getvalue().split(_END_FOLDER)


def kml_chunks(scene: SceneStream, name: str = "rfsas run") -> Iterator[bytes]:
    """The scene as a KML document, in pieces as it is read.

    Sensors come first but are known only at the end, so the fixes and the
    bearings wait in :class:`~rfsas_hw.exports.spill.Spool` files meanwhile;
    the tracks come from the scene's compact track columns.

    Raises:
        OutputError: a temporary file cannot be written.
    """
    head, *tails = _skeleton(name)
    with Spool() as fixes, Spool() as bearings:
        for mark in scene.marks():
            if isinstance(mark, FixMark):
                fixes.write(_text(_fix(mark)))
            else:
                bearings.write(_text(_bearing(mark)))
        sections: list[Iterable[bytes]] = [
            (_text(_sensor(s)) for s in scene.sensors()),
            fixes.blocks(),
            bearings.blocks(),
            (_text(_track(t)) for t in scene.tracks()),
        ]
        yield head
        for section, tail in zip(sections, tails, strict=True):
            yield from section
            yield _END_FOLDER + tail


def write_kml(scene: SceneStream, path: str | Path, name: str = "rfsas run") -> Path:
    """Write the scene as KML to ``path`` as it is read.

    Raises:
        ConfigError: the file cannot be created.
        OutputError: writing it failed (disk full); the target is unchanged.
    """
    p = Path(path)
    write_chunks_atomic(p, kml_chunks(scene, name))
    return p
