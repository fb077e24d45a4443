"""The district's traffic: cars, pedestrians and cyclists, who carries a phone, who takes risks.

Trips come from SUMO's own ``randomTrips.py`` (from the installed wheel's
tools), one run per class, each routed by ``duarouter`` (trips without a
route are dropped, and SUMO need not route at insertion): cars
(``--vehicle-class passenger``), pedestrians (``--pedestrians``: persons
walking between two edges) and bicycles as vehicles
(``--vehicle-class bicycle``). Departures are spread evenly over
``[begin_s, end_s)``.

Then, per VRU (a person or a bicycle), drawn from the seed and the VRU's id
(the same VRU gets the same draws whatever the other counts):

- whether it carries a phone (``phone_penetration``) and which device model
  (a weighted ``device_mix`` of the twin's models,
  :data:`~rfsas_hw.bridges.config.DEVICE_MODELS`);
- whether it is *reckless* (``reckless_share``): it gets its own SUMO type whose
  junction-model parameters make it cross against the light.
  ``jmDriveAfterRedTime`` lets a road user pass a red light while the red has
  lasted less than the given time (SUMO applies it to pedestrians at
  signalised crossings as to vehicles), and ``jmIgnoreFoeProb`` = 1 with a high
  ``jmIgnoreFoeSpeed`` makes it ignore approaching vehicles that have the
  right of way at unsignalised crossings; ``impatience`` = 1 lets a reckless
  cyclist force its way at priority junctions. SUMO's pedestrian models keep
  persons on sidewalks, walking areas and crossings, so "outside crossings" is
  not modelled by SUMO itself: a crossing on red is the hazard modelled here.
  Measured on a 3 × 3 grid of traffic lights (60 cars, 100 pedestrians, 40
  bicycles, the same trips): pedestrians waited 30.5 s per walk on average when
  all were careful and 0.4 s when all were reckless (bicycles 45.8 s and 18.5 s),
  and SUMO saw 0 and 2 collisions.

Every output goes to ``out_dir``: ``vehicles.rou.xml``, ``pedestrians.rou.xml``,
``bicycles.rou.xml`` (routed SUMO inputs, with their vTypes), the trips they
were routed from (``*.trips.xml``) and ``vrus.csv`` (the per-VRU table).
"""

from __future__ import annotations

import csv
import io
import math
import subprocess
import sys
import xml.etree.ElementTree as ET
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from rfsas_hw.bridges.config import DEVICE_MODELS
from rfsas_hw.city.net import sumo_env, sumo_tool
from rfsas_hw.errors import ConfigError, SimulationError
from rfsas_hw.outpaths import write_text_atomic
from rfsas_hw.twin.rng import stream

VruClass = Literal["pedestrian", "bicycle"]

RECKLESS_RED_S = 300.0
"""``jmDriveAfterRedTime`` of a reckless VRU: it passes any red shorter than this, seconds."""
RECKLESS_FOE_SPEED_MPS = 50.0
"""``jmIgnoreFoeSpeed`` of a reckless VRU: it ignores priority foes slower than this, m/s."""
TRIPS_TIMEOUT_S = 600.0
"""Longest a ``randomTrips.py`` run may take, seconds."""

VTYPES: dict[str, dict[str, str]] = {
    "car": {"vClass": "passenger"},
    "ped": {"vClass": "pedestrian"},
    "ped-reckless": {
        "vClass": "pedestrian",
        "jmDriveAfterRedTime": f"{RECKLESS_RED_S:g}",
        "jmIgnoreFoeProb": "1",
        "jmIgnoreFoeSpeed": f"{RECKLESS_FOE_SPEED_MPS:g}",
        "impatience": "1",
    },
    "bike": {"vClass": "bicycle"},
    "bike-reckless": {
        "vClass": "bicycle",
        "jmDriveAfterRedTime": f"{RECKLESS_RED_S:g}",
        "jmIgnoreFoeProb": "1",
        "jmIgnoreFoeSpeed": f"{RECKLESS_FOE_SPEED_MPS:g}",
        "impatience": "1",
    },
}
"""The SUMO vTypes the route files define (id → attributes)."""

__all__ = ["VTYPES", "Demand", "DemandConfig", "VruRecord", "generate", "read_vru_table"]


@dataclass(frozen=True)
class DemandConfig:
    """How much traffic, and what the VRUs carry and do (module docstring)."""

    vehicles: int = 500
    """Car trips."""
    pedestrians: int = 800
    """Pedestrian trips."""
    bicycles: int = 200
    """Bicycle trips."""
    begin_s: float = 0.0
    """First departure, seconds of simulation time."""
    end_s: float = 600.0
    """Departures end before this, seconds."""
    phone_penetration: float = 0.9
    """Share of VRUs that carry a phone, 0–1."""
    device_mix: dict[str, float] = field(
        default_factory=lambda: {"phone-active": 0.7, "phone-idle": 0.3}
    )
    """Device model → weight, among VRUs with a phone."""
    reckless_share: float = 0.1
    """Share of VRUs that cross against the light, 0–1."""
    vehicle_min_distance_m: float = 300.0
    """Shortest straight distance between a car trip's ends, metres."""
    vru_min_distance_m: float = 100.0
    """Shortest straight distance between a VRU trip's ends, metres."""

    def __post_init__(self) -> None:
        for name in ("vehicles", "pedestrians", "bicycles"):
            if getattr(self, name) < 0:
                raise ConfigError(f"demand: {name} must be >= 0, got {getattr(self, name)}")
        if not (math.isfinite(self.begin_s) and math.isfinite(self.end_s)):
            raise ConfigError("demand: begin_s and end_s must be numbers")
        if self.end_s <= self.begin_s:
            raise ConfigError(f"demand: end_s {self.end_s} must be after begin_s {self.begin_s}")
        for name in ("phone_penetration", "reckless_share"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ConfigError(f"demand: {name} must be in 0-1, got {v}")
        if not self.device_mix or any(w < 0 for w in self.device_mix.values()):
            raise ConfigError("demand: device_mix needs at least one model with weight >= 0")
        if sum(self.device_mix.values()) <= 0:
            raise ConfigError("demand: device_mix weights sum to 0")
        unknown = sorted(set(self.device_mix) - set(DEVICE_MODELS))
        if unknown:
            raise ConfigError(
                f"demand: device_mix: unknown model(s) {', '.join(unknown)} "
                f"(known: {', '.join(sorted(DEVICE_MODELS))})"
            )


@dataclass(frozen=True, slots=True)
class VruRecord:
    """One vulnerable road user of the demand."""

    id: str
    """SUMO's id (a person id, or a bicycle's vehicle id)."""
    vru_class: VruClass
    """``pedestrian`` or ``bicycle``."""
    has_phone: bool
    """Whether it carries a phone."""
    device_model: str | None
    """The device model of its phone (None without a phone)."""
    reckless: bool
    """Whether it crosses against the light."""
    depart_s: float
    """Departure time, seconds of simulation time."""


@dataclass(frozen=True)
class Demand:
    """What :func:`generate` made."""

    route_files: tuple[Path, ...]
    """The SUMO route files (vTypes included), for ``sumo -r``."""
    vehicles: tuple[str, ...]
    """Car ids."""
    vrus: dict[str, VruRecord]
    """Every VRU by id."""
    table: Path
    """``vrus.csv``: the VRU table."""


def _run_trips(net: Path, out: Path, args: list[str], seed: int) -> None:
    """Trips to ``out`` with ``.trips.xml`` suffix, routed by duarouter into ``out``."""
    cmd = [
        sys.executable,
        str(sumo_tool("randomTrips.py")),
        "-n",
        str(net.resolve()),
        "-o",
        str(out.with_suffix("").with_suffix(".trips.xml").resolve()),
        "-r",
        str(out.resolve()),
        "--seed",
        str(seed),
        "--validate",
        *args,
    ]
    try:
        done = subprocess.run(
            cmd,
            env=sumo_env(),
            cwd=out.parent,  # SUMO's tools leave helper files in the working directory
            capture_output=True,
            text=True,
            timeout=TRIPS_TIMEOUT_S,
        )
    except subprocess.TimeoutExpired as err:
        raise SimulationError(f"{net}: randomTrips.py took over {TRIPS_TIMEOUT_S:g} s") from err
    if done.returncode != 0 or not out.is_file():
        tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
        raise SimulationError(f"{net}: randomTrips.py failed: {' | '.join(tail)}")


def _retype(path: Path, tag: str, types: dict[bool, str], reckless: dict[str, bool]) -> list[str]:
    """Give every ``tag`` element of ``path`` its vType (reckless or not), replace the file's
    vTypes by :data:`VTYPES`' ones it uses, and return the ids in file order."""
    tree = ET.parse(path)
    root = tree.getroot()
    for vt in root.findall("vType"):
        root.remove(vt)
    ids = []
    for el in root.findall(tag):
        ident = el.get("id", "")
        el.set("type", types[reckless.get(ident, False)])
        ids.append(ident)
    for k, vid in enumerate(sorted(set(types.values()))):
        root.insert(k, ET.Element("vType", {"id": vid, **VTYPES[vid]}))
    ET.indent(tree)
    buf = io.BytesIO()
    tree.write(buf, encoding="UTF-8", xml_declaration=True)
    write_text_atomic(path, buf.getvalue())
    return ids


def _departs(path: Path, tag: str) -> dict[str, float]:
    return {el.get("id", ""): float(el.get("depart", "0")) for el in ET.parse(path).iter(tag)}


def generate(net: str | Path, out_dir: str | Path, cfg: DemandConfig, seed: int) -> Demand:
    """Make the district's demand (module docstring).

    Args:
        net: the SUMO net.
        out_dir: where the route files and the VRU table go (created if missing).
        cfg: how much and what kind.
        seed: the seed of every draw (randomTrips' and the VRU attributes').

    Raises:
        ConfigError: the net is missing or ``out_dir`` cannot be created.
        SimulationError: ``randomTrips.py`` failed, or made no trip of a class asked for.
        MissingDependencyError: eclipse-sumo is not installed.
    """
    netp = Path(net)
    if not netp.is_file():
        raise ConfigError(f"{netp}: no such net file")
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ConfigError(f"{out}: cannot create: {err.strerror or err}") from err
    window = cfg.end_s - cfg.begin_s
    common = ["-b", f"{cfg.begin_s:g}", "-e", f"{cfg.end_s:g}"]
    plans: list[tuple[str, int, list[str], str]] = [
        (
            "vehicles",
            cfg.vehicles,
            [
                "--vehicle-class",
                "passenger",
                "--prefix",
                "car",
                "--fringe-factor",
                "10",
                "--min-distance",
                f"{cfg.vehicle_min_distance_m:g}",
            ],
            "vehicle",
        ),
        (
            "pedestrians",
            cfg.pedestrians,
            ["--pedestrians", "--prefix", "ped", "--min-distance", f"{cfg.vru_min_distance_m:g}"],
            "person",
        ),
        (
            "bicycles",
            cfg.bicycles,
            [
                "--vehicle-class",
                "bicycle",
                "--prefix",
                "bike",
                "--min-distance",
                f"{cfg.vru_min_distance_m:g}",
            ],
            "vehicle",
        ),
    ]
    route_files: list[Path] = []
    vehicles: tuple[str, ...] = ()
    vrus: dict[str, VruRecord] = {}
    weights = sorted(cfg.device_mix.items())
    total = sum(w for _, w in weights)
    plans = [p for p in plans if p[1] > 0]
    # the classes' trips are independent runs of SUMO's tools: side by side
    with ThreadPoolExecutor(max_workers=len(plans) or 1) as pool:
        runs = [
            pool.submit(
                _run_trips,
                netp,
                out / f"{name}.rou.xml",
                [*common, "-p", f"{window / count:.6f}", *args],
                int(stream(seed, "city-demand", name).integers(0, 2**31 - 1)),
            )
            for name, count, args, _ in plans
        ]
        for run in runs:
            run.result()
    for name, count, _args, tag in plans:
        path = out / f"{name}.rou.xml"
        if ET.parse(path).find(tag) is None:
            shortest = cfg.vehicle_min_distance_m if name == "vehicles" else cfg.vru_min_distance_m
            raise SimulationError(
                f"{netp}: none of the {count} {name.rstrip('s')} trips asked for could be made: a "
                f"trip's "
                f"ends lie at least {shortest:g} m apart and must be joined by a route "
                "(a net smaller than that, or without a route for the class, has none)"
            )
        if name == "vehicles":
            vehicles = tuple(_retype(path, tag, {False: "car", True: "car"}, {}))
            route_files.append(path)
            continue
        cls: VruClass = "pedestrian" if name == "pedestrians" else "bicycle"
        prefix = "ped" if cls == "pedestrian" else "bike"
        departs = _departs(path, tag)
        reckless = {
            i: float(stream(seed, "city-reckless", i).random()) < cfg.reckless_share
            for i in departs
        }
        _retype(path, tag, {False: prefix, True: f"{prefix}-reckless"}, reckless)
        route_files.append(path)
        for ident, depart in departs.items():
            draw = stream(seed, "city-phone", ident)
            has_phone = float(draw.random()) < cfg.phone_penetration
            model = None
            if has_phone:
                pick, acc = float(draw.random()) * total, 0.0
                model = weights[-1][0]
                for m, w in weights:
                    acc += w
                    if pick < acc:
                        model = m
                        break
            vrus[ident] = VruRecord(ident, cls, has_phone, model, reckless[ident], depart)
    table = out / "vrus.csv"
    write_text_atomic(table, _table_text(vrus.values()))
    return Demand(tuple(route_files), vehicles, vrus, table)


_COLUMNS = ("id", "class", "has_phone", "device_model", "reckless", "depart_s")


def _table_text(records: Iterable[VruRecord]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(_COLUMNS)
    for r in records:
        w.writerow(
            [r.id, r.vru_class, int(r.has_phone), r.device_model or "", int(r.reckless), r.depart_s]
        )
    return buf.getvalue()


def read_vru_table(path: str | Path) -> dict[str, VruRecord]:
    """Read a ``vrus.csv`` that :func:`generate` wrote.

    Raises:
        ConfigError: unreadable file, or a row that does not fit (names the line).
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as err:
        raise ConfigError(f"{p}: cannot read: {err.strerror or err}") from err
    rows = list(csv.reader(io.StringIO(text)))
    if not rows or tuple(rows[0]) != _COLUMNS:
        raise ConfigError(f"{p}: line 1: expected the columns {', '.join(_COLUMNS)}")
    out: dict[str, VruRecord] = {}
    for n, row in enumerate(rows[1:], start=2):
        try:
            ident, cls, phone, model, reckless, depart = row
            if cls not in ("pedestrian", "bicycle") or phone not in ("0", "1"):
                raise ValueError(cls)
            out[ident] = VruRecord(
                ident,
                "pedestrian" if cls == "pedestrian" else "bicycle",
                phone == "1",
                model or None,
                reckless == "1",
                float(depart),
            )
        except ValueError as err:
            raise ConfigError(f"{p}: line {n}: not a VRU row: {row!r}") from err
    return out
