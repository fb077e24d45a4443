"""CARLA sensor against fakes built from the real ``carla`` client types (no server)."""

from __future__ import annotations

import fnmatch
import math
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import pytest

carla = pytest.importorskip("carla", reason="needs the carla extra: pip install 'rfsas-hw[carla]'")

from rfsas_hw.bridges.bridge import Bridge  # noqa: E402
from rfsas_hw.bridges.carla import (  # noqa: E402
    CarlaControl,
    CarlaRfsasSensor,
    actor_entity,
    read_buildings,
)
from rfsas_hw.bridges.config import bridge_config_from_mapping  # noqa: E402
from rfsas_hw.errors import SimulationError  # noqa: E402

from .helpers import config_data  # noqa: E402

ORIGIN = (100.0, 200.0)
"""The junction's centre in CARLA's coordinates."""


@dataclass
class FakeActor:
    """An actor whose state is made of real carla types."""

    id: int
    type_id: str
    transform: Any
    velocity: Any
    extent: Any
    attributes: dict[str, str] = field(default_factory=dict)
    is_alive: bool = True
    controls: list[Any] = field(default_factory=list)
    autopilot: list[bool] = field(default_factory=list)

    @property
    def bounding_box(self) -> Any:
        return carla.BoundingBox(carla.Location(0.0, 0.0, self.extent.z), self.extent)

    def get_transform(self) -> Any:
        return self.transform

    def get_velocity(self) -> Any:
        return self.velocity

    def get_control(self) -> Any:
        return (
            self.controls[-1] if self.controls else carla.VehicleControl(throttle=0.4, steer=0.05)
        )

    def apply_control(self, control: Any) -> None:
        self.controls.append(control)

    def set_autopilot(self, on: bool) -> None:
        self.autopilot.append(on)


class ActorList(list[FakeActor]):
    def filter(self, pattern: str) -> list[FakeActor]:
        return [a for a in self if fnmatch.fnmatch(a.type_id, pattern)]


class FakeWorld:
    def __init__(self, actors: list[FakeActor], buildings: list[Any] = ()) -> None:  # type: ignore[assignment]
        self.actors = ActorList(actors)
        self.t = 0.0
        self.buildings = list(buildings)

    def get_actors(self) -> ActorList:
        return self.actors

    def get_snapshot(self) -> Any:
        return SimpleNamespace(timestamp=SimpleNamespace(elapsed_seconds=self.t))

    def get_environment_objects(self, label: Any) -> list[Any]:
        assert label == carla.CityObjectLabel.Buildings
        return self.buildings


def _actor(
    aid: int, type_id: str, x: float, y: float, yaw: float, speed: float, **kw: Any
) -> FakeActor:
    a = math.radians(yaw)
    return FakeActor(
        aid,
        type_id,
        carla.Transform(carla.Location(x, y, 0.5), carla.Rotation(yaw=yaw)),
        carla.Vector3D(speed * math.cos(a), speed * math.sin(a), 0.0),
        kw.pop("extent", carla.Vector3D(2.3, 0.9, 0.7)),
        **kw,
    )


def test_left_handed_frame_and_kinds() -> None:
    # yaw -90: facing CARLA's -y, which is north
    ego = _actor(1, "vehicle.tesla.model3", 101.75, 240.0, -90.0, 10.0)
    e = actor_entity(ego, "ego", ORIGIN)
    assert (e.x_m, e.y_m) == pytest.approx((1.75, -40.0))
    assert e.heading_deg == pytest.approx(0.0, abs=1e-9) and e.speed_mps == pytest.approx(10.0)
    assert (e.length_m, e.width_m) == pytest.approx((4.6, 1.8))
    walker = _actor(
        7, "walker.pedestrian.0001", 95.0, 204.0, 0.0, 1.4, extent=carla.Vector3D(0.3, 0.3, 0.9)
    )
    w = actor_entity(walker, origin=ORIGIN)
    assert w.kind == "pedestrian" and w.id == "pedestrian-7"
    assert (w.x_m, w.y_m, w.heading_deg) == pytest.approx((-5.0, -4.0, 90.0))
    bike = _actor(
        8, "vehicle.bh.crossbike", 100.0, 190.0, 90.0, 5.0, attributes={"number_of_wheels": "2"}
    )
    b = actor_entity(bike, origin=ORIGIN)
    assert b.kind == "cyclist" and b.heading_deg == pytest.approx(180.0)
    # the box centre is the bounding box's offset turned by the actor's transform
    off = _actor(9, "vehicle.audi.tt", 100.0, 200.0, 90.0, 0.0)
    off_bb = carla.BoundingBox(carla.Location(1.0, 0.0, 0.7), carla.Vector3D(2.0, 1.0, 0.7))
    shifted = SimpleNamespace(
        id=9,
        type_id=off.type_id,
        attributes={},
        bounding_box=off_bb,
        get_transform=off.get_transform,
        get_velocity=off.get_velocity,
    )
    assert actor_entity(shifted, origin=ORIGIN).y_m == pytest.approx(-1.0)  # 1 m south


def test_buildings_become_rfsas_rectangles() -> None:
    box = carla.BoundingBox(carla.Location(80.0, 220.0, 10.0), carla.Vector3D(10.0, 5.0, 10.0))
    shed = carla.BoundingBox(carla.Location(0.0, 0.0, 1.0), carla.Vector3D(0.5, 0.5, 1.0))
    world = FakeWorld(
        [],
        [
            SimpleNamespace(id=1, name="b1", bounding_box=box),
            SimpleNamespace(id=2, name="shed", bounding_box=shed),
        ],
    )
    (b,) = read_buildings(world, ORIGIN)
    assert (b.x_min_m, b.x_max_m, b.y_min_m, b.y_max_m) == pytest.approx(
        (-30.0, -10.0, -25.0, -15.0)
    )


def _drive(autopilot: bool) -> tuple[FakeActor, list[str], list[str]]:
    """The ego drives north at 10 m/s towards a pedestrian walking east across its lane."""
    cfg = bridge_config_from_mapping(config_data(), "units")
    ego = _actor(1, "vehicle.tesla.model3", ORIGIN[0] + 1.75, ORIGIN[1] + 50.0, -90.0, 10.0)
    ped = _actor(
        2,
        "walker.pedestrian.0002",
        ORIGIN[0] - 6.0,
        ORIGIN[1] + 4.0,
        0.0,
        1.4,
        extent=carla.Vector3D(0.3, 0.3, 0.9),
    )
    world = FakeWorld([ego, ped])
    advisories: list[str] = []
    actions: list[str] = []
    with Bridge(cfg) as bridge:
        sensor = CarlaRfsasSensor(
            world, ego, bridge, origin=ORIGIN, control=CarlaControl(hold_s=0.5), autopilot=autopilot
        )
        speed = 10.0
        for k in range(45):
            world.t = 0.1 * k
            res = sensor.tick()
            advisories.append(res.advisory)
            actions.append("brake" if sensor.braking else "-")
            if sensor.braking:
                speed = max(speed - 0.8, 0.0)  # what the server's physics would do
            loc = ego.transform.location
            ego.transform = carla.Transform(
                carla.Location(loc.x, loc.y - speed * 0.1, 0.5), carla.Rotation(yaw=-90.0)
            )
            ego.velocity = carla.Vector3D(0.0, -speed, 0.0)
            pl = ped.transform.location
            ped.transform = carla.Transform(
                carla.Location(pl.x + 0.14, pl.y, 0.5), carla.Rotation(yaw=0.0)
            )
    return ego, advisories, actions


def test_each_tick_feeds_the_bridge_and_brakes_the_ego() -> None:
    ego, advisories, actions = _drive(autopilot=True)
    assert "brake" in advisories
    first = advisories.index("brake")
    assert actions[first] == "brake"
    braking = [c for c in ego.controls if c.brake > 0]
    assert braking and all(c.brake == 1.0 and c.throttle == 0.0 for c in braking)
    # the steering is kept; the autopilot is off while braking and back afterwards
    assert braking[0].steer == pytest.approx(0.05)
    assert ego.autopilot[0] is False
    if "brake" not in actions[-3:]:
        assert ego.autopilot[-1] is True


def test_a_dead_ego_is_named() -> None:
    cfg = bridge_config_from_mapping(config_data(), "units")
    ego = _actor(1, "vehicle.tesla.model3", 0.0, 0.0, 0.0, 0.0)
    ego.is_alive = False
    with Bridge(cfg) as bridge:
        sensor = CarlaRfsasSensor(FakeWorld([ego]), ego, bridge)
        with pytest.raises(SimulationError, match="actor 1"):
            sensor.tick()
