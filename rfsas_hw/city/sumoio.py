"""SUMO for a district: everyone's state each step in arrays, and each vehicle's own BRAKE.

:class:`SumoDistrict` subscribes to every vehicle and person when it departs
(libsumo or TraCI subscriptions: one call per step returns every value) and
returns them per step as :class:`Movers` arrays in the rfsas frame of the net
(:class:`~rfsas_hw.city.net.NetInfo`): a vehicle's front-bumper position moves
back half its length to the box centre, SUMO's angle turns into a compass
heading of the frame. Two-wheelers (:data:`~rfsas_hw.bridges.vru_score.VRU_VCLASSES`)
and persons are the VRUs; every other vehicle is a vehicle to advise.

:meth:`SumoDistrict.act` applies one vehicle's advisory through that vehicle's
own :class:`~rfsas_hw.bridges.sumo.SumoAdapter` (BRAKE stops it and holds it
for ``hold_s``; CLEAR hands it back to SUMO), so a vehicle brakes only for
its own BRAKE.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.bridges.sumo import SumoAdapter, SumoControl
from rfsas_hw.bridges.vru_score import PERSON, VRU_VCLASSES

Array = npt.NDArray[np.float64]

_POSITION, _SPEED, _ANGLE, _DISTANCE = 0x42, 0x40, 0x43, 0x84
"""TraCI variable ids (``traci.constants``): position, speed, angle, odometer."""

__all__ = ["Movers", "SumoDistrict"]


@dataclass(frozen=True)
class Movers:
    """Vehicles or VRUs at one step, rfsas frame, box centres."""

    ids: tuple[str, ...]
    """SUMO ids (persons and vehicles as SUMO names them)."""
    cls: tuple[str, ...]
    """``pedestrian``, ``bicycle``, ``moped``, ``motorcycle`` for VRUs; SUMO's vehicle
    class for vehicles."""
    x_m: Array
    """East of the origin, metres."""
    y_m: Array
    """North of the origin, metres."""
    heading_deg: Array
    """Compass degrees in the frame."""
    speed_mps: Array
    length_m: Array
    width_m: Array
    odometer_m: Array
    """Distance driven since departure, metres (0 for persons)."""

    def __len__(self) -> int:
        return len(self.ids)


@dataclass(frozen=True)
class _Static:
    cls: str
    length_m: float
    width_m: float
    vru: bool
    person: bool


class SumoDistrict:
    """Reads a running SUMO each step and steers vehicles (see the module docstring).

    Args:
        sumo: the ``libsumo`` or ``traci`` module with a simulation started.
        to_frame: net coordinates → frame (east, north) metres, arrays.
        heading_to_frame: SUMO angles → frame compass degrees, arrays.
        control: how advisories act on a vehicle.
    """

    def __init__(
        self,
        sumo: ModuleType,
        to_frame: Any,
        heading_to_frame: Any,
        control: SumoControl | None = None,
    ) -> None:
        self.sumo = sumo
        self.to_frame = to_frame
        self.heading_to_frame = heading_to_frame
        self.control = control or SumoControl()
        self._static: dict[str, _Static] = {}
        self._adapters: dict[str, SumoAdapter] = {}
        self._vehicle_vars = (_POSITION, _SPEED, _ANGLE, _DISTANCE)
        self._person_vars = (_POSITION, _SPEED, _ANGLE)

    def _subscribe(self) -> None:
        sumo = self.sumo
        for vid in sumo.simulation.getDepartedIDList():
            vclass = str(sumo.vehicle.getVehicleClass(vid))
            self._static[vid] = _Static(
                vclass,
                float(sumo.vehicle.getLength(vid)),
                float(sumo.vehicle.getWidth(vid)),
                vclass in VRU_VCLASSES,
                False,
            )
            sumo.vehicle.subscribe(vid, self._vehicle_vars)
        for pid in sumo.simulation.getDepartedPersonIDList():
            self._static[pid] = _Static(
                PERSON,
                float(sumo.person.getLength(pid)),
                float(sumo.person.getWidth(pid)),
                True,
                True,
            )
            sumo.person.subscribe(pid, self._person_vars)
        for vid in sumo.simulation.getArrivedIDList():
            self._static.pop(vid, None)
            self._adapters.pop(vid, None)
        for pid in sumo.simulation.getArrivedPersonIDList():
            self._static.pop(pid, None)

    def _movers(self, results: dict[str, dict[int, Any]], vru: bool) -> Movers:
        static = self._static
        rows = [(k, st, r) for k, r in results.items() if (st := static.get(k)) and st.vru == vru]
        n = len(rows)
        # one list per column, then one array each (element-wise numpy writes cost more)
        xy = np.array([r[_POSITION] for _, _, r in rows], dtype=np.float64).reshape(n, 2)
        angle = np.array([r[_ANGLE] for _, _, r in rows], dtype=np.float64)
        speed = np.array([r[_SPEED] for _, _, r in rows], dtype=np.float64)
        odo = np.array([r.get(_DISTANCE, 0.0) for _, _, r in rows], dtype=np.float64)
        length = np.array([s.length_m for _, s, _ in rows], dtype=np.float64)
        width = np.array([s.width_m for _, s, _ in rows], dtype=np.float64)
        e, nn = self.to_frame(xy[:, 0], xy[:, 1])
        heading = np.asarray(self.heading_to_frame(angle), dtype=np.float64)
        # SUMO gives a vehicle's front bumper and a person's centre
        back = np.array([0.0 if st.person else st.length_m / 2 for _, st, _ in rows])
        rad = np.radians(heading)
        e = np.asarray(e, dtype=np.float64) - back * np.sin(rad)
        nn = np.asarray(nn, dtype=np.float64) - back * np.cos(rad)
        return Movers(
            ids=tuple(k for k, _, _ in rows),
            cls=tuple(st.cls for _, st, _ in rows),
            x_m=e,
            y_m=nn,
            heading_deg=heading,
            speed_mps=np.maximum(speed, 0.0),
            length_m=length,
            width_m=width,
            odometer_m=odo,
        )

    def read(self) -> tuple[Movers, Movers]:
        """The vehicles and the VRUs now (call once after every simulation step)."""
        self._subscribe()
        vehicles = self.sumo.vehicle.getAllSubscriptionResults()
        persons = self.sumo.person.getAllSubscriptionResults()
        cars = self._movers(vehicles, vru=False)
        vrus_v = self._movers(vehicles, vru=True)
        vrus_p = self._movers(persons, vru=True)
        return cars, _concat(vrus_v, vrus_p)

    def act(self, t_s: float, vehicle_id: str, advisory: str) -> str:
        """Apply ``advisory`` to ``vehicle_id`` at ``t_s``; what was done (as
        :meth:`SumoAdapter.act`), ``gone`` when the vehicle has left."""
        if vehicle_id not in self._static:
            return "gone"
        adapter = self._adapters.get(vehicle_id)
        if adapter is None:
            if advisory not in ("brake", "caution"):
                return "none"
            adapter = SumoAdapter(self.sumo, vehicle_id, control=self.control)
            self._adapters[vehicle_id] = adapter
        return adapter.act(t_s, advisory)

    def held(self) -> list[str]:
        """Vehicles an advisory acts on now (braking, held or capped)."""
        return list(self._adapters)

    def release_idle(self, t_s: float, advised: set[str]) -> None:
        """Let vehicles that got no advisory this step go on when their hold is over."""
        for vid in [v for v in self._adapters if v not in advised]:
            if self.act(t_s, vid, "none") in ("release", "none", "gone"):
                self._adapters.pop(vid, None)


def _concat(a: Movers, b: Movers) -> Movers:
    return Movers(
        ids=a.ids + b.ids,
        cls=a.cls + b.cls,
        x_m=np.concatenate([a.x_m, b.x_m]),
        y_m=np.concatenate([a.y_m, b.y_m]),
        heading_deg=np.concatenate([a.heading_deg, b.heading_deg]),
        speed_mps=np.concatenate([a.speed_mps, b.speed_mps]),
        length_m=np.concatenate([a.length_m, b.length_m]),
        width_m=np.concatenate([a.width_m, b.width_m]),
        odometer_m=np.concatenate([a.odometer_m, b.odometer_m]),
    )
