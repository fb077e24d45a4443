"""The test track in SUMO: a straight road, the VUT, the targets and the parked vehicles.

The road is a hand-written SUMO network (:func:`network_xml`): an eastbound
and a westbound edge, each with a car lane and a sidewalk, 350 m long, in
the frame of :mod:`rfsas_hw.ncap.scenarios`. The VUT is a SUMO vehicle whose
speed the controllers set every step (speed mode 0: SUMO's own rules and
limits are off, the brake model is the controllers'); the targets are SUMO
persons and ``bicycle`` vehicles moved along their planned paths with
``moveToXY`` (as the protocol's dummies run on a platform); a turning VUT
(CPTA, CBTA) is placed on its planned path with ``moveToXY`` too, each step
as far along it as its speed took it (the free area beside the road stands
in for the side street); the parked
vehicles are SUMO polygons of type ``parked-vehicle``. Every entity is read
back through :class:`~rfsas_hw.bridges.sumo.SumoAdapter`, so the scoring and
RF-SAS see exactly what a ``rfsas sumo run`` would.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path
from types import ModuleType
from typing import Any

from rfsas_hw.bridges.bridge import Entity
from rfsas_hw.bridges.sumo import SumoAdapter, load_sumo, start_sumo
from rfsas_hw.bridges.vru_score import vru_class
from rfsas_hw.errors import SimulationError
from rfsas_hw.ncap.scenarios import LANE_WIDTH_M, VUT_LENGTH_M, VUT_WIDTH_M, Plan
from rfsas_hw.twin.scenario import BuildingSpec

ROAD_X_M = (-250.0, 100.0)
"""Where the road starts and ends, metres east."""
STEP_S = 0.05
"""SUMO's step, seconds."""
EGO = "ego"
OBSTACLE_TYPE = "parked-vehicle"
"""SUMO polygon type of a parked obstruction vehicle."""
OCCLUDER_TYPES = ("building", OBSTACLE_TYPE)
"""SUMO polygon types that block line of sight."""

__all__ = ["EGO", "STEP_S", "SumoWorld", "network_xml"]


def network_xml() -> str:
    """The straight test road as a SUMO network (see the module docstring)."""
    x0, x1 = ROAD_X_M
    length = x1 - x0
    w = LANE_WIDTH_M
    side = -(w / 2 + 3.3)  # sidewalk centre beyond a 2 m parking strip
    far = w
    far_side = far + w / 2 + 3.3

    def lane(lid: str, idx: int, allow: str, width: float, y: float, back: bool) -> str:
        a, b = (x1, x0) if back else (x0, x1)
        return (
            f'        <lane id="{lid}" index="{idx}" {allow} speed="30.00" length="{length:.2f}" '
            f'width="{width:.2f}" shape="{a:.2f},{y:.2f} {b:.2f},{y:.2f}"/>\n'
        )

    return (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        '<net version="1.20" junctionCornerDetail="5" limitTurnSpeed="5.50">\n'
        f'    <location netOffset="0.00,0.00" convBoundary="{x0:.2f},-10.00,{x1:.2f},12.00" '
        f'origBoundary="{x0:.2f},-10.00,{x1:.2f},12.00" projParameter="!"/>\n'
        '    <edge id="east" from="W" to="E" priority="1">\n'
        + lane("east_0", 0, 'allow="pedestrian"', 2.0, side, False)
        + lane("east_1", 1, 'disallow="pedestrian"', w, 0.0, False)
        + "    </edge>\n"
        '    <edge id="west" from="E" to="W" priority="1">\n'
        + lane("west_0", 0, 'allow="pedestrian"', 2.0, far_side, True)
        + lane("west_1", 1, 'disallow="pedestrian"', w, far, True)
        + "    </edge>\n"
        f'    <junction id="W" type="dead_end" x="{x0:.2f}" y="0.00" incLanes="west_0 west_1" '
        f'intLanes="" shape="{x0:.2f},{far_side + 1:.2f} {x0:.2f},{side - 1:.2f}"/>\n'
        f'    <junction id="E" type="dead_end" x="{x1:.2f}" y="0.00" incLanes="east_0 east_1" '
        f'intLanes="" shape="{x1:.2f},{side - 1:.2f} {x1:.2f},{far_side + 1:.2f}"/>\n'
        "</net>\n"
    )


class SumoWorld:
    """One run's SUMO simulation (see the module docstring).

    Raises:
        MissingDependencyError: libsumo is not installed.
        SimulationError: SUMO does not start or the VUT is not inserted.
    """

    def __init__(self, plan: Plan, *, seed: int = 0) -> None:
        self.plan = plan
        self.sumo: ModuleType = load_sumo("libsumo")
        with tempfile.TemporaryDirectory(prefix="rfsas-ncap-") as tmp:
            net = Path(tmp) / "road.net.xml"
            net.write_text(network_xml(), encoding="utf-8")
            cmd = ["sumo", "-n", str(net), "--step-length", f"{STEP_S}", "--seed", str(seed)]
            cmd += ["--collision.action", "warn", "--collision.check-junctions", "true"]
            cmd += ["--no-step-log", "true", "--no-warnings", "true"]
            start_sumo(self.sumo, cmd)
        self._closed = False
        try:
            self._populate()
        except Exception:
            self.close()
            raise
        self.adapter = SumoAdapter(self.sumo, EGO)
        self.t_s = 0.0
        """Run time, seconds (0 when the VUT starts)."""
        self.vut_s_m = 0.0
        """How far the VUT has driven, metres."""

    def _populate(self) -> None:
        s = self.sumo
        p = self.plan
        s.route.add("east-route", ["east"])
        s.route.add("west-route", ["west"])
        s.vehicletype.copy("DEFAULT_VEHTYPE", "vut")
        s.vehicletype.setLength("vut", VUT_LENGTH_M)
        s.vehicletype.setWidth("vut", VUT_WIDTH_M)
        s.vehicletype.setMaxSpeed("vut", 30.0)
        # one step of driving before its start: the step that puts the targets in place
        front = p.vut_start_x_m - p.vut_speed_mps * STEP_S + VUT_LENGTH_M / 2 - ROAD_X_M[0]
        s.vehicle.add(
            EGO, "east-route", typeID="vut", departPos=f"{front:.3f}",
            departSpeed=f"{p.vut_speed_mps:.4f}", departLane="1",
        )  # fmt: skip
        for path in p.targets:
            tid = f"{path.id}-type"
            if path.kind == "pedestrian":
                s.vehicletype.copy("DEFAULT_PEDTYPE", tid)
                s.vehicletype.setLength(tid, path.length_m)
                s.vehicletype.setWidth(tid, path.width_m)
                s.person.add(path.id, "west", 10.0, typeID=tid)
                s.person.appendWalkingStage(path.id, ["west"], 300.0)
            else:
                s.vehicletype.copy("DEFAULT_BIKETYPE", tid)
                s.vehicletype.setLength(tid, path.length_m)
                s.vehicletype.setWidth(tid, path.width_m)
                s.vehicle.add(path.id, "west-route", typeID=tid, departPos="5", departLane="1")
        for ob in p.obstacles:
            shape = [
                (ob.x_min_m, ob.y_min_m), (ob.x_max_m, ob.y_min_m),
                (ob.x_max_m, ob.y_max_m), (ob.x_min_m, ob.y_max_m),
            ]  # fmt: skip
            s.polygon.add(ob.name, shape, (90, 90, 90, 255), True, OBSTACLE_TYPE, 1)
        s.simulationStep()  # insert everyone
        if EGO not in s.vehicle.getIDList():
            raise SimulationError("SUMO did not insert the VUT")
        s.vehicle.setSpeedMode(EGO, 0)
        # SUMO inserts the targets where their routes begin (the road's far end) and moves
        # them with the next step: that step is taken here, so that the first read (t = 0)
        # finds everyone where the plan puts them, not 100 m down the road
        self._place(0.0)
        self._drive(0.0, p.vut_speed_mps)

    def _place(self, t_s: float) -> None:
        s = self.sumo
        for path in self.plan.targets:
            x, y, _ = path.at(t_s)
            h = path.heading_deg
            if path.kind == "pedestrian":
                s.person.moveToXY(path.id, "", x, y, angle=h, keepRoute=2)
            else:  # SUMO places a vehicle by its front bumper
                a = math.radians(h)
                fx, fy = x + path.length_m / 2 * math.sin(a), y + path.length_m / 2 * math.cos(a)
                s.vehicle.moveToXY(path.id, "", 0, fx, fy, angle=h, keepRoute=2)

    def step(self, vut_speed_mps: float) -> float:
        """Move the targets to their next places, drive the VUT at ``vut_speed_mps`` for one
        step; the new run time, seconds."""
        t_next = self.t_s + STEP_S
        v = max(vut_speed_mps, 0.0)
        self._place(t_next)
        self.vut_s_m += v * STEP_S
        self._drive(self.vut_s_m, v)
        self.t_s = t_next
        return t_next

    def _drive(self, s_m: float, v: float) -> None:
        """One SUMO step with the VUT at ``v`` m/s, a turning VUT placed ``s_m`` metres along
        its path (as SUMO's own step would place it)."""
        path = self.plan.vut_path
        if path is not None:
            x, y, h = path.pose(s_m)
            a = math.radians(h)
            fx, fy = x + VUT_LENGTH_M / 2 * math.sin(a), y + VUT_LENGTH_M / 2 * math.cos(a)
            self.sumo.vehicle.moveToXY(EGO, "", 0, fx, fy, angle=h, keepRoute=2)
        self.sumo.vehicle.setSpeed(EGO, v)
        self.sumo.simulationStep()

    def read(self) -> tuple[Entity, list[tuple[Entity, str]]]:
        """The VUT and every VRU with its class.

        Raises:
            SimulationError: the VUT has left the road.
        """
        ego, others = self.adapter.read()
        if ego is None:
            raise SimulationError(f"the VUT left the road at {self.t_s:.2f} s")
        vrus = []
        for o in others:
            cls = vru_class(o.kind, self.adapter.vehicle_class(o.id))
            if cls is not None:
                vrus.append((o, cls))
        return ego, vrus

    def collisions(self) -> list[Any]:
        """SUMO's own collision list of the last step."""
        return list(self.sumo.simulation.getCollisions())

    def occluders(self) -> list[BuildingSpec]:
        """Every SUMO polygon that blocks sight, as its bounding rectangle (rfsas frame)."""
        s = self.sumo
        out = []
        for pid in s.polygon.getIDList():
            if s.polygon.getType(pid) not in OCCLUDER_TYPES:
                continue
            xs = [q[0] for q in s.polygon.getShape(pid)]
            ys = [q[1] for q in s.polygon.getShape(pid)]
            out.append(BuildingSpec(min(xs), max(xs), min(ys), max(ys), name=str(pid)))
        return out

    def close(self) -> None:
        """End the SUMO simulation; idempotent."""
        if not self._closed:
            self._closed = True
            self.sumo.close()

    def __enter__(self) -> SumoWorld:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
