"""The offline path: SUMO's FCD output → an rfsas scenario → ``rfsas sim capture``.

SUMO's floating car data (``--fcd-output``) lists, per time step, every
vehicle's and person's position, angle and speed. :func:`fcd_to_scenario`
turns the samples into scenario movers (one waypoint per sample, standing
samples as pauses), gives every entity the device the live bridge would give
it (same seed, same penetration draw, same MAC: :func:`~rfsas_hw.bridges.bridge.device_model_of`,
:func:`~rfsas_hw.bridges.bridge.device_mac`), places the units of a bridge
configuration (the ego's unit rides on the ego) and adds the buildings of a
SUMO polygon file. The result is an ordinary scenario mapping: write it with
:func:`write_scenario` and run ``rfsas sim capture`` on it.

Vehicle positions in FCD are front bumpers, as in TraCI; they are moved to
the box centre with the vehicle length (the ``length`` attribute when the
FCD has it, else ``vehicle_length_m``). MAC rotation is not reproduced
offline: each entity keeps its first MAC.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from rfsas_hw.bridges.bridge import EGO_MOVER, device_mac, device_model_of
from rfsas_hw.bridges.config import BridgeConfig, EgoUnitSpec, UnitSpec
from rfsas_hw.bridges.coords import FRAMES
from rfsas_hw.bridges.sumofiles import check_no_dtd
from rfsas_hw.errors import DataFormatError, SimulationError
from rfsas_hw.outpaths import write_text_atomic
from rfsas_hw.records import int_to_mac
from rfsas_hw.twin.scenario import BuildingSpec, scenario_from_mapping

__all__ = ["buildings_from_poly_file", "fcd_to_scenario", "read_fcd", "write_scenario"]

_STILL_M = 1e-6


@dataclass
class FcdTrack:
    """One entity's samples from an FCD file, in the rfsas frame."""

    id: str
    """Entity id (persons get the ``person:`` prefix, as in the live adapter)."""
    kind: str
    """``pedestrian`` or ``vehicle``."""
    t_s: list[float] = field(default_factory=list)
    x_m: list[float] = field(default_factory=list)
    y_m: list[float] = field(default_factory=list)
    length_m: float = 0.5
    width_m: float = 0.5


def _float(el: ET.Element, name: str, where: str, default: float | None = None) -> float:
    if name not in el.attrib and default is not None:
        return default
    try:
        value = float(el.attrib[name])
    except KeyError:
        raise DataFormatError(f"{where}: <{el.tag}> has no {name!r} attribute") from None
    except ValueError:
        raise DataFormatError(f"{where}: {name}={el.attrib[name]!r} is not a number") from None
    if not math.isfinite(value):
        raise DataFormatError(f"{where}: {name}={el.attrib[name]!r} is not a finite number")
    return value


def read_fcd(
    path: str | Path, origin: tuple[float, float], *, vehicle_length_m: float = 4.5
) -> dict[str, FcdTrack]:
    """Every entity's samples of an FCD file, box centres in the rfsas frame.

    Raises:
        DataFormatError: not an FCD file, a sample without position or time or
            with a value that is not a finite number, an unreadable file.
        ConfigError: the file declares a DTD.
    """
    p = Path(path)
    sumo = FRAMES["sumo"]
    tracks: dict[str, FcdTrack] = {}
    t = math.nan
    check_no_dtd(p)  # entities a DTD defines would expand without bound
    try:
        for event, el in ET.iterparse(p, events=("start", "end")):
            if event == "start" and el.tag == "timestep":
                t = _float(el, "time", f"{p}")
            elif event == "end" and el.tag in ("vehicle", "person"):
                where = f"{p}: time {t:g}"
                vid = el.attrib.get("id")
                if vid is None or math.isnan(t):
                    raise DataFormatError(f"{where}: <{el.tag}> without id or outside a timestep")
                person = el.tag == "person"
                eid = f"person:{vid}" if person else vid
                length = _float(el, "length", where, 0.5 if person else vehicle_length_m)
                e, n, _ = sumo.to_rfsas(
                    _float(el, "x", where),
                    _float(el, "y", where),
                    _float(el, "angle", where),
                    length_m=length,
                    reference="centre" if person else "front-bumper",
                    origin=origin,
                )
                tr = tracks.get(eid)
                if tr is None:
                    kind = "pedestrian" if person else "vehicle"
                    width = _float(el, "width", where, 0.5 if person else 1.8)
                    tr = tracks[eid] = FcdTrack(eid, kind, length_m=length, width_m=width)
                tr.t_s.append(t)
                tr.x_m.append(float(e))
                tr.y_m.append(float(n))
                el.clear()
    except ET.ParseError as err:
        raise DataFormatError(f"{p}: not valid XML: {err}") from err
    except OSError as err:
        raise DataFormatError(f"{p}: cannot read: {err.strerror or err}") from err
    if not tracks:
        raise DataFormatError(f"{p}: no vehicle or person samples (is it an FCD file?)")
    return tracks


def buildings_from_poly_file(path: str | Path, origin: tuple[float, float]) -> list[BuildingSpec]:
    """The ``building`` polygons of a SUMO additional file, as rfsas-frame bounding rectangles.

    Raises:
        DataFormatError: unreadable file or a malformed shape.
    """
    p = Path(path)
    try:
        root = ET.parse(p).getroot()
    except (ET.ParseError, OSError) as err:
        raise DataFormatError(f"{p}: cannot read polygons: {err}") from err
    out = []
    for poly in root.iter("poly"):
        if poly.attrib.get("type") != "building":
            continue
        try:
            pts = [
                tuple(float(v) for v in xy.split(",")[:2]) for xy in poly.attrib["shape"].split()
            ]
        except (KeyError, ValueError) as err:
            raise DataFormatError(f"{p}: poly {poly.attrib.get('id')!r}: bad shape") from err
        xs = [x - origin[0] for x, _ in pts]
        ys = [y - origin[1] for _, y in pts]
        if max(xs) > min(xs) and max(ys) > min(ys):
            out.append(
                BuildingSpec(min(xs), max(xs), min(ys), max(ys), name=poly.attrib.get("id", ""))
            )
    return out


def _waypoints(tr: FcdTrack) -> list[dict[str, float]]:
    """One waypoint per place: samples that do not move become a pause there."""
    wps: list[dict[str, float]] = []
    n = len(tr.t_s)
    k = 0
    while k < n:
        x, y = tr.x_m[k], tr.y_m[k]
        j = k
        while j + 1 < n and math.hypot(tr.x_m[j + 1] - x, tr.y_m[j + 1] - y) <= _STILL_M:
            j += 1
        wp: dict[str, float] = {"x_m": x, "y_m": y}
        if tr.t_s[j] > tr.t_s[k]:
            wp["pause_s"] = tr.t_s[j] - tr.t_s[k]
        if j + 1 < n:
            d = math.hypot(tr.x_m[j + 1] - x, tr.y_m[j + 1] - y)
            wp["speed_mps"] = d / (tr.t_s[j + 1] - tr.t_s[j])
        wps.append(wp)
        k = j + 1
    return wps


def _unit(u: UnitSpec | EgoUnitSpec) -> dict[str, Any]:
    out: dict[str, Any] = {
        "id": u.id,
        "receiver": u.receiver,
        "antenna": _plain(u.antenna),
        "driver": _plain(u.driver),
        "scan": _plain(u.scan),
        "threshold_dbm": dict(u.threshold_dbm),
    }
    if u.calibration != "turntable":
        out["calibration"] = u.calibration
    if isinstance(u, UnitSpec):
        out.update(kind="roadside", pose=_plain(u.pose))
    else:
        out.update(kind="on-board", mounted_on=EGO_MOVER, heading_offset_deg=u.heading_offset_deg)
    return out


def _plain(obj: Any) -> Any:
    from dataclasses import asdict, is_dataclass

    if is_dataclass(obj) and not isinstance(obj, type):
        return {k: _plain(v) for k, v in asdict(obj).items() if v is not None}
    if isinstance(obj, tuple | list):
        return [_plain(v) for v in obj]
    return obj


def fcd_to_scenario(
    fcd_path: str | Path,
    config: BridgeConfig,
    *,
    ego: str,
    buildings: list[BuildingSpec] | None = None,
    name: str = "sumo-fcd",
    vehicle_length_m: float = 4.5,
) -> dict[str, Any]:
    """The scenario mapping of an FCD run (see the module docstring).

    Args:
        fcd_path: SUMO's FCD output.
        config: the bridge settings (units, devices, seed, RF, buildings).
        ego: the ego vehicle's SUMO id (its mover is called ``ego``).
        buildings: more buildings (e.g. :func:`buildings_from_poly_file`).
        name: the scenario's name.
        vehicle_length_m: vehicle length when the FCD has none, metres.

    Raises:
        DataFormatError: a bad FCD file.
        SimulationError: the ego is not in it.
        ConfigError: the result is not a valid scenario (checked by loading it).
    """
    tracks = read_fcd(fcd_path, config.origin_m, vehicle_length_m=vehicle_length_m)
    if ego not in tracks:
        raise SimulationError(f"{fcd_path}: no vehicle {ego!r} (the ego) in the FCD output")
    t0 = min(tr.t_s[0] for tr in tracks.values())
    t_end = max(tr.t_s[-1] for tr in tracks.values())
    movers = []
    emitters = []
    for eid, tr in tracks.items():
        tr.t_s = [t - t0 for t in tr.t_s]
        mover_id = EGO_MOVER if eid == ego else eid
        movers.append(
            {
                "id": mover_id,
                "kind": tr.kind,
                "start_s": tr.t_s[0],
                "waypoints": _waypoints(tr),
                "length_m": tr.length_m,
                "width_m": tr.width_m,
            }
        )
        if eid == ego:
            continue
        model_name = device_model_of(config, eid, tr.kind)  # type: ignore[arg-type]
        if model_name is None:
            continue
        model = config.device_model(model_name)
        emitters.append(
            {
                "id": f"{eid}#0",
                "mac": int_to_mac(device_mac(config, eid, 0)),
                "tech": model.tech,
                "traffic": _plain(model.traffic),
                "antenna_gain_dbi": model.antenna_gain_dbi,
                "carried_by": eid,
                **({"tx_power_dbm": model.tx_power_dbm} if model.tx_power_dbm is not None else {}),
            }
        )
    units = [_unit(u) for u in config.units]
    if config.ego_unit is not None:
        units.append(_unit(config.ego_unit))
    data: dict[str, Any] = {
        "version": 1,
        "name": name,
        "seed": config.seed,
        "duration_s": max(t_end - t0, 0.1),
        "start_utc": config.start_utc,
        "detail": config.detail,
        "ego": EGO_MOVER,
        "rf": _plain(config.rf),
        "intersection": {"buildings": _plain([*config.buildings, *(buildings or [])])},
        "movers": movers,
        "emitters": emitters,
        "sensors": units,
        "description": f"from SUMO FCD output {Path(fcd_path).name}",
    }
    scenario_from_mapping(data, f"{fcd_path} (converted)")
    return data


def write_scenario(data: dict[str, Any], path: str | Path) -> Path:
    """Write a scenario mapping as YAML (beside the target, then renamed over it).

    Raises:
        ConfigError: the file cannot be created.
        OutputError: writing it failed (disk full); the target is unchanged.
    """
    p = Path(path)
    write_text_atomic(p, yaml.safe_dump(data, sort_keys=False))
    return p
