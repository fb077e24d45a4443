"""SUMO for a district: everyone's state each step in arrays, and each vehicle's own BRAKE.

:class:`SumoDistrict` reads every vehicle and person each step through libsumo's
getters and returns them as :class:`Movers` arrays in the rfsas frame of the net
(:class:`~rfsas_hw.city.net.NetInfo`): a vehicle's front-bumper position moves
back half its length to the box centre, SUMO's angle turns into a compass
heading of the frame. Two-wheelers (:data:`~rfsas_hw.bridges.vru_score.VRU_VCLASSES`)
and persons are the VRUs; every other vehicle is a vehicle to advise.

Why getters and not subscriptions: with libsumo a getter is a function call, and
a subscription makes SUMO build every subscribed value of every object at the
end of each step. Measured on the Adlershof district's demand (1,000 simulated
steps, 935 persons and up to 709 vehicles), subscriptions made SUMO's own steps
cost about half again as much, for the same values read (``docs/city-log.md``,
"This round: the simulator's lag"). Over TraCI's socket each getter would be a
round trip; the district runs libsumo.

:meth:`SumoDistrict.act` applies one vehicle's advisory through that vehicle's
own :class:`~rfsas_hw.bridges.sumo.SumoAdapter` (BRAKE stops it and holds it
for ``hold_s``; CLEAR hands it back to SUMO), so a vehicle brakes only for
its own BRAKE.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import chain
from types import ModuleType
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.bridges.sumo import SumoAdapter, SumoControl
from rfsas_hw.bridges.vru_score import PERSON, VRU_VCLASSES

Array = npt.NDArray[np.float64]

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
    """Distance driven since departure, metres (vehicles; 0 for VRUs: nothing uses theirs,
    and every value read costs libsumo time each step)."""

    def __len__(self) -> int:
        return len(self.ids)


@dataclass(frozen=True, slots=True)
class _Static:
    """What does not change while an object is in the simulation."""

    cls: str
    sizes: tuple[float, float, float]
    """Length, width, and how far SUMO's reference point lies ahead of the box centre
    (half the length for a vehicle's front bumper, 0 for a person), metres."""
    vru: bool


class SumoDistrict:
    """Reads a running SUMO each step and steers vehicles (see the module docstring).

    Args:
        sumo: the ``libsumo`` module with a simulation started.
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

    def _learn(self) -> None:
        """Learn the class and size of what departed in the last step; forget what
        arrived."""
        sumo = self.sumo
        for vid in sumo.simulation.getDepartedIDList():
            vclass = str(sumo.vehicle.getVehicleClass(vid))
            length = float(sumo.vehicle.getLength(vid))
            width = float(sumo.vehicle.getWidth(vid))
            vru = vclass in VRU_VCLASSES
            self._static[vid] = _Static(vclass, (length, width, length / 2), vru)
        for pid in sumo.simulation.getDepartedPersonIDList():
            length = float(sumo.person.getLength(pid))
            width = float(sumo.person.getWidth(pid))
            self._static[pid] = _Static(PERSON, (length, width, 0.0), True)
        for vid in sumo.simulation.getArrivedIDList():
            self._static.pop(vid, None)
            self._adapters.pop(vid, None)
        for pid in sumo.simulation.getArrivedPersonIDList():
            self._static.pop(pid, None)

    def _movers(self, keys: list[str], values: list[tuple[float, ...]]) -> Movers:
        """Movers of ``keys`` from ``values`` (per key: x, y, angle, speed, odometer as SUMO
        gives them, in the order of ``keys``)."""
        n = len(keys)
        static = self._static
        sts = [static[k] for k in keys]
        # flat float streams into one array each: per-element numpy writes, or arrays
        # from lists of tuples, cost several times more at a thousand objects
        dyn = np.fromiter(chain.from_iterable(values), np.float64, 5 * n).reshape(n, 5)
        sizes = np.fromiter(
            chain.from_iterable([st.sizes for st in sts]), np.float64, 3 * n
        ).reshape(n, 3)
        e, nn = self.to_frame(dyn[:, 0], dyn[:, 1])
        heading = np.asarray(self.heading_to_frame(dyn[:, 2]), dtype=np.float64)
        # SUMO gives a vehicle's front bumper and a person's centre
        back = sizes[:, 2]
        rad = np.radians(heading)
        e = np.asarray(e, dtype=np.float64) - back * np.sin(rad)
        nn = np.asarray(nn, dtype=np.float64) - back * np.cos(rad)
        return Movers(
            ids=tuple(keys),
            cls=tuple([st.cls for st in sts]),
            x_m=e,
            y_m=nn,
            heading_deg=heading,
            speed_mps=np.maximum(dyn[:, 3], 0.0),
            length_m=sizes[:, 0].copy(),
            width_m=sizes[:, 1].copy(),
            odometer_m=dyn[:, 4].copy(),
        )

    def read(self) -> tuple[Movers, Movers]:
        """The vehicles and the VRUs now (call once after every simulation step)."""
        self._learn()
        sumo = self.sumo
        static = self._static
        car_ids: list[str] = []
        vru_ids: list[str] = []
        for k in sumo.vehicle.getIDList():
            st = static.get(k)
            if st is not None:
                (vru_ids if st.vru else car_ids).append(k)
        bikes = len(vru_ids)
        # the VRUs: the two-wheelers first, then the persons
        vru_ids += [k for k in sumo.person.getIDList() if k in static]
        veh, per = sumo.vehicle, sumo.person
        pos, ang, spd, odo = veh.getPosition, veh.getAngle, veh.getSpeed, veh.getDistance
        # the odometer for vehicles only: nothing uses a VRU's, and each value costs a call
        cars = [(*pos(k), ang(k), spd(k), odo(k)) for k in car_ids]
        vrus = [(*pos(k), ang(k), spd(k), 0.0) for k in vru_ids[:bikes]]
        pos, ang, spd = per.getPosition, per.getAngle, per.getSpeed
        vrus += [(*pos(k), ang(k), spd(k), 0.0) for k in vru_ids[bikes:]]
        return self._movers(car_ids, cars), self._movers(vru_ids, vrus)

    def act(self, t_s: float, vehicle_id: str, advisory: str) -> str:
        """Apply ``advisory`` to ``vehicle_id`` at ``t_s``; what was done (as
        :meth:`SumoAdapter.act`), ``gone`` when the vehicle has left (as of the last
        :meth:`read`)."""
        if vehicle_id not in self._static:
            return "gone"
        adapter = self._adapters.get(vehicle_id)
        if adapter is None:
            if advisory not in ("brake", "caution"):
                return "none"
            adapter = SumoAdapter(self.sumo, vehicle_id, control=self.control)
            self._adapters[vehicle_id] = adapter
        return adapter.steer(t_s, advisory)

    def held(self) -> list[str]:
        """Vehicles an advisory acts on now (braking, held or capped)."""
        return list(self._adapters)

    def release_idle(self, t_s: float, advised: set[str]) -> None:
        """Let vehicles that got no advisory this step go on when their hold is over."""
        for vid in [v for v in self._adapters if v not in advised]:
            if self.act(t_s, vid, "none") in ("release", "none", "gone"):
                self._adapters.pop(vid, None)
