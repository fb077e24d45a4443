"""The SUMO adapter: persons and vehicles in, the ego's speed out.

Works with ``libsumo`` (SUMO inside this process: fast, one simulation at a
time, no GUI) or ``traci`` (a SUMO started by us or elsewhere, e.g. beside
Veins; needed for ``sumo-gui``). Both expose the same API, so the adapter is
given the module.

Each step :meth:`SumoAdapter.read` converts every person and vehicle to an
:class:`~rfsas_hw.bridges.bridge.Entity` in the rfsas frame (SUMO reports a
vehicle's front bumper; :mod:`rfsas_hw.bridges.coords` moves it to the box
centre), and :meth:`SumoAdapter.act` turns the advisory into speed commands:
BRAKE stops the ego through ``vehicle.setSpeed(ego, 0)`` (SUMO applies the
type's deceleration) and holds it for ``hold_s``; CAUTION after a BRAKE keeps
the speed the ego came down to, and caps it when a cap is configured; CLEAR
(or nothing tracked) hands the ego back to SUMO.

Buildings come from SUMO polygons of type ``building`` (:func:`read_buildings`),
each taken as its bounding rectangle (the twin's buildings are axis-aligned).
"""

from __future__ import annotations

import logging
import math
import os
import sys
import tempfile
from dataclasses import dataclass
from types import ModuleType
from typing import Literal

from rfsas_hw.bridges.bridge import Entity
from rfsas_hw.bridges.config import EntityKind
from rfsas_hw.bridges.coords import FRAMES
from rfsas_hw.errors import ConfigError, MissingDependencyError, SimulationError
from rfsas_hw.twin.scenario import BuildingSpec

SumoApi = Literal["libsumo", "traci"]
BUILDING_TYPES = ("building",)
"""SUMO polygon types read as buildings."""
BUILDING_LOSS_DB = 20.0
"""Extra loss of a path through a SUMO building, dB."""

__all__ = ["SumoAdapter", "SumoControl", "load_sumo", "read_buildings", "start_sumo"]

log = logging.getLogger(__name__)


def load_sumo(api: SumoApi) -> ModuleType:
    """The ``libsumo`` or ``traci`` module.

    Raises:
        MissingDependencyError: it is not installed (names the install command).
        ConfigError: an unknown API name.
    """
    if api not in ("libsumo", "traci"):
        raise ConfigError(f"SUMO API must be libsumo or traci, not {api!r}")
    try:
        import importlib

        return importlib.import_module(api)
    except ImportError as err:
        raise MissingDependencyError(
            f"{api} is not installed; install it with: pip install 'rfsas-hw[sumo]'"
        ) from err


def start_sumo(sumo: ModuleType, cmd: list[str]) -> None:
    """Start SUMO with ``cmd`` through ``sumo`` (libsumo or traci).

    libsumo writes SUMO's own reasons to this process's standard error and raises
    only "Process Error": its messages while starting are caught (standard error is
    a temporary file for that moment) and its ``Error:`` lines end the raised
    message; any other lines it wrote are logged at WARNING. A traci SUMO is a
    process of its own and keeps writing to the console.

    Raises:
        SimulationError: SUMO did not start, with SUMO's reason when it gave one.
    """
    if getattr(sumo, "__name__", "") != "libsumo":
        try:
            sumo.start(cmd)
        except Exception as err:  # traci raises its own types
            raise SimulationError(f"SUMO did not start: {err}") from err
        return
    failed: Exception | None = None
    with tempfile.TemporaryFile() as capture:
        sys.stderr.flush()
        saved = os.dup(2)
        os.dup2(capture.fileno(), 2)
        try:
            sumo.start(cmd)
        except Exception as err:  # libsumo's TraCIException
            failed = err
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        capture.seek(0)
        lines = capture.read(1 << 20).decode("utf-8", "replace").splitlines()
    errors = [ln.split(":", 1)[1].strip() for ln in lines if ln.startswith("Error:")]
    for line in (ln for ln in lines if ln.strip() and not ln.startswith("Error:")):
        log.warning("SUMO: %s", line.strip())
    if failed is None:
        return
    reason = "; ".join(errors[-3:]) if errors else str(failed)
    raise SimulationError(f"SUMO did not start: {reason}") from failed


def read_buildings(sumo: ModuleType, origin: tuple[float, float]) -> list[BuildingSpec]:
    """Every polygon of type ``building`` as an rfsas-frame rectangle (its bounding box)."""
    out = []
    for pid in sumo.polygon.getIDList():
        if sumo.polygon.getType(pid) not in BUILDING_TYPES:
            continue
        shape = sumo.polygon.getShape(pid)
        xs = [p[0] - origin[0] for p in shape]
        ys = [p[1] - origin[1] for p in shape]
        if max(xs) > min(xs) and max(ys) > min(ys):
            out.append(
                BuildingSpec(
                    x_min_m=min(xs),
                    x_max_m=max(xs),
                    y_min_m=min(ys),
                    y_max_m=max(ys),
                    name=str(pid),
                    loss_db=BUILDING_LOSS_DB,
                )
            )
    return out


@dataclass(frozen=True)
class SumoControl:
    """How the adapter acts on advisories."""

    hold_s: float = 1.0
    """A BRAKE holds the ego stopped until no BRAKE came for this long, seconds."""
    caution_speed_mps: float | None = None
    """Speed cap while CAUTION is the advisory, m/s (None: no cap)."""

    def __post_init__(self) -> None:
        if self.hold_s < 0:
            raise ValueError("hold_s must be >= 0")
        if self.caution_speed_mps is not None and self.caution_speed_mps < 0:
            raise ValueError("caution_speed_mps must be >= 0")


def _kind_of_vehicle(v_class: str) -> EntityKind:
    return "cyclist" if v_class == "bicycle" else "vehicle"


class SumoAdapter:
    """Reads SUMO's persons and vehicles and steers the ego (see the module docstring).

    Args:
        sumo: the ``libsumo`` or ``traci`` module, with a simulation started.
        ego_id: the ego vehicle's SUMO id.
        origin: the site origin in SUMO's net coordinates, metres.
        control: how advisories act on the ego.
    """

    def __init__(
        self,
        sumo: ModuleType,
        ego_id: str,
        *,
        origin: tuple[float, float] = (0.0, 0.0),
        control: SumoControl | None = None,
    ) -> None:
        self.sumo = sumo
        self.ego_id = ego_id
        self.origin = origin
        self.control = control or SumoControl()
        self.frame = FRAMES["sumo"]
        self._braking_until = -math.inf
        self._capped = False
        self._vclass: dict[str, str] = {}
        self.ego_seen = False

    def _vehicle(self, vid: str, kind: EntityKind) -> Entity:
        v = self.sumo.vehicle
        return Entity.from_sim(
            self.frame,
            vid,
            kind,
            v.getPosition(vid),
            v.getAngle(vid),
            speed_mps=v.getSpeed(vid),
            length_m=v.getLength(vid),
            width_m=v.getWidth(vid),
            reference="front-bumper",
            origin=self.origin,
        )

    def vehicle_class(self, entity_id: str) -> str | None:
        """SUMO's vehicle class of a vehicle read before (None: a person or never read)."""
        return self._vclass.get(entity_id)

    def read(self) -> tuple[Entity | None, list[Entity]]:
        """The ego (None while it is not in the network) and every other entity now."""
        sumo = self.sumo
        ego: Entity | None = None
        others: list[Entity] = []
        for vid in sumo.vehicle.getIDList():
            if vid == self.ego_id:
                ego = self._vehicle(vid, "vehicle")
                self.ego_seen = True
                continue
            if vid not in self._vclass:
                self._vclass[vid] = str(sumo.vehicle.getVehicleClass(vid))
            others.append(self._vehicle(vid, _kind_of_vehicle(self._vclass[vid])))
        p = sumo.person
        for pid in p.getIDList():
            others.append(
                Entity.from_sim(
                    self.frame,
                    f"person:{pid}",
                    "pedestrian",
                    p.getPosition(pid),
                    p.getAngle(pid),
                    speed_mps=p.getSpeed(pid),
                    length_m=p.getLength(pid),
                    width_m=p.getWidth(pid),
                    reference="centre",
                    origin=self.origin,
                )
            )
        return ego, others

    def act(self, t_s: float, advisory: str) -> str:
        """Apply ``advisory`` to the ego at ``t_s``; what was done (``brake``, ``hold``,
        ``cap``, ``release`` or ``none``).

        Raises:
            SimulationError: the ego is not in the network.
        """
        if self.ego_id not in self.sumo.vehicle.getIDList():
            raise SimulationError(f"ego vehicle {self.ego_id!r} is not in the simulation")
        return self.steer(t_s, advisory)

    def steer(self, t_s: float, advisory: str) -> str:
        """:meth:`act` for an ego the caller knows to be in the simulation (it skips
        asking SUMO for every vehicle's id, a list as long as the traffic, which a caller
        steering many vehicles per step cannot afford each time)."""
        v = self.sumo.vehicle
        if advisory == "brake":
            self._braking_until = t_s + self.control.hold_s
            v.setSpeed(self.ego_id, 0.0)
            return "brake"
        if t_s < self._braking_until:
            return "hold"
        cap = self.control.caution_speed_mps
        braked = self._braking_until > -math.inf
        if advisory == "caution" and (cap is not None or braked):
            # after a BRAKE, CAUTION keeps the speed the ego came down to: no speeding up
            # towards a threat that is still there, only CLEAR releases it
            speed = float(v.getSpeed(self.ego_id))
            v.setSpeed(self.ego_id, speed if cap is None else min(speed, cap))
            self._capped = True
            return "cap"
        if self._capped or self._braking_until > -math.inf:
            v.setSpeed(self.ego_id, -1.0)
            self._capped = False
            self._braking_until = -math.inf
            return "release"
        return "none"
