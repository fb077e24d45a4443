"""CARLA: a client-side RF-SAS sensor that reads the world each tick and can brake the ego.

CARLA (the ``carla`` extra: the 0.9.16 client; the server needs a GPU) has
walkers, vehicles and buildings but no sensor for where a phone is. This
sensor lives in the Python client: each tick :meth:`CarlaRfsasSensor.tick`

1. reads every walker (``walker.*``) and vehicle (``vehicle.*``) from the
   ``carla.World``: ``get_transform()``, ``get_velocity()``,
   ``bounding_box`` (its centre, through the actor's transform, and its
   extent); two-wheeled vehicles (blueprint attribute ``number_of_wheels``
   ``2``) are cyclists;
2. converts CARLA's left-handed Unreal frame (``y`` points south; yaw in
   degrees from ``x`` towards ``y``) to the rfsas frame with
   :data:`rfsas_hw.bridges.coords.FRAMES` ``["carla"]``;
3. feeds the :class:`~rfsas_hw.bridges.bridge.Bridge` with the snapshot's
   ``elapsed_seconds``;
4. on a BRAKE advisory (when ``control.brake`` is set), applies
   ``carla.VehicleControl(throttle=0, brake=1)`` to the ego, keeping its
   steering, for ``control.hold_s`` after the last BRAKE; an ego on autopilot
   is taken off it while braking and put back afterwards (the Traffic
   Manager would otherwise overwrite the control on the next tick).

:func:`read_buildings` turns CARLA's building objects
(``world.get_environment_objects(carla.CityObjectLabel.Buildings)``) into the
twin's axis-aligned footprints (each object's bounding rectangle in the
rfsas frame).

In synchronous mode call :meth:`~CarlaRfsasSensor.tick` after each
``world.tick()``; in asynchronous mode register it with
``world.on_tick(sensor.on_snapshot)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from rfsas_hw.bridges.adapter import Snapshot
from rfsas_hw.bridges.bridge import Bridge, Entity, StepResult
from rfsas_hw.bridges.config import EntityKind
from rfsas_hw.bridges.coords import FRAMES
from rfsas_hw.errors import MissingDependencyError, SimulationError
from rfsas_hw.twin.scenario import BuildingSpec

FRAME = FRAMES["carla"]
BUILDING_LOSS_DB = 20.0
"""Extra loss of a path through a CARLA building, dB."""

__all__ = ["CarlaControl", "CarlaRfsasSensor", "actor_entity", "read_buildings", "require_carla"]


def require_carla() -> Any:
    """The ``carla`` client module.

    Raises:
        MissingDependencyError: it is not installed (names the install command).
    """
    try:
        import carla
    except ImportError as err:
        raise MissingDependencyError(
            "the CARLA client is not installed; install it with: pip install 'rfsas-hw[carla]'"
        ) from err
    return carla


@dataclass(frozen=True)
class CarlaControl:
    """How the sensor acts on advisories."""

    brake: bool = True
    """Apply full brake to the ego on BRAKE (False: only report)."""
    hold_s: float = 1.0
    """Keep braking this long after the last BRAKE, seconds."""
    brake_level: float = 1.0
    """``VehicleControl.brake`` while braking, 0–1."""

    def __post_init__(self) -> None:
        if self.hold_s < 0:
            raise ValueError("hold_s must be >= 0")
        if not 0.0 < self.brake_level <= 1.0:
            raise ValueError("brake_level must be in (0, 1]")


def _kind(actor: Any) -> EntityKind:
    if str(actor.type_id).startswith("walker."):
        return "pedestrian"
    wheels = getattr(actor, "attributes", {}).get("number_of_wheels")
    return "cyclist" if str(wheels) == "2" else "vehicle"


def actor_entity(
    actor: Any, eid: str | None = None, origin: tuple[float, float] = (0.0, 0.0)
) -> Entity:
    """An actor as an :class:`~rfsas_hw.bridges.bridge.Entity` in the rfsas frame.

    The position is the centre of the actor's bounding box (its offset from
    the actor's origin turned by the actor's transform); the speed is the
    horizontal speed.
    """
    tf = actor.get_transform()
    bb = actor.bounding_box
    centre = tf.transform(bb.location)
    v = actor.get_velocity()
    return Entity.from_sim(
        FRAME,
        eid if eid is not None else f"{_kind(actor)}-{actor.id}",
        _kind(actor),
        (centre.x, centre.y),
        tf.rotation.yaw,
        speed_mps=math.hypot(v.x, v.y),
        length_m=max(2.0 * float(bb.extent.x), 0.1),
        width_m=max(2.0 * float(bb.extent.y), 0.1),
        origin=origin,
    )


def read_buildings(
    world: Any, origin: tuple[float, float] = (0.0, 0.0), *, min_area_m2: float = 4.0
) -> list[BuildingSpec]:
    """CARLA's building objects as rfsas-frame rectangles (bounding rectangles).

    Args:
        world: a ``carla.World``.
        origin: the site origin in CARLA's coordinates, metres.
        min_area_m2: smaller footprints (sheds, signs) are left out.
    """
    carla = require_carla()
    out = []
    identity = carla.Transform()
    for obj in world.get_environment_objects(carla.CityObjectLabel.Buildings):
        corners = obj.bounding_box.get_world_vertices(identity)
        xs = np.array([c.x for c in corners])
        ys = np.array([c.y for c in corners])
        e, n, _ = FRAME.to_rfsas(xs, ys, 0.0, origin=origin)
        if (e.max() - e.min()) * (n.max() - n.min()) < min_area_m2:
            continue
        out.append(
            BuildingSpec(
                x_min_m=float(e.min()),
                x_max_m=float(e.max()),
                y_min_m=float(n.min()),
                y_max_m=float(n.max()),
                name=str(getattr(obj, "name", obj.id)),
                loss_db=BUILDING_LOSS_DB,
            )
        )
    return out


class CarlaRfsasSensor:
    """RF-SAS for a CARLA world, run by the client (see the module docstring).

    Args:
        world: the ``carla.World``.
        ego: the ego vehicle actor.
        bridge: the bridge (its units in the rfsas frame, relative to ``origin``).
        origin: the site origin in CARLA's coordinates, metres.
        control: how advisories act on the ego.
        autopilot: whether the ego drives on the Traffic Manager's autopilot.
    """

    def __init__(
        self,
        world: Any,
        ego: Any,
        bridge: Bridge,
        *,
        origin: tuple[float, float] = (0.0, 0.0),
        control: CarlaControl | None = None,
        autopilot: bool = False,
    ) -> None:
        self.world = world
        self.ego = ego
        self.bridge = bridge
        self.origin = origin
        self.control = control or CarlaControl()
        self.autopilot = autopilot
        self.last: StepResult | None = None
        """The bridge's result at the last tick."""
        self.braking = False
        """Whether the sensor holds the ego's brake now."""
        self._hold_until = -math.inf

    def read(self, elapsed_s: float | None = None) -> Snapshot:
        """The ego and every other walker and vehicle now (rfsas frame)."""
        t = (
            float(self.world.get_snapshot().timestamp.elapsed_seconds)
            if elapsed_s is None
            else float(elapsed_s)
        )
        actors = self.world.get_actors()
        others = []
        for pattern in ("walker.*", "vehicle.*"):
            for a in actors.filter(pattern):
                if a.id == self.ego.id:
                    continue
                others.append(actor_entity(a, origin=self.origin))
        return Snapshot(t, actor_entity(self.ego, "ego", self.origin), tuple(others))

    def tick(self, elapsed_s: float | None = None) -> StepResult:
        """Read the world, run the bridge, act on its advisory (see the module docstring).

        Raises:
            SimulationError: the ego is no longer alive, or time did not advance.
        """
        if not getattr(self.ego, "is_alive", True):
            raise SimulationError(f"CARLA: the ego vehicle (actor {self.ego.id}) is gone")
        snap = self.read(elapsed_s)
        result = self.bridge.step(snap.t_s, snap.ego, snap.entities)
        self.last = result
        self.act(snap.t_s, result.advisory)
        return result

    def on_snapshot(self, snapshot: Any) -> None:
        """``world.on_tick`` callback (asynchronous mode)."""
        self.tick(float(snapshot.timestamp.elapsed_seconds))

    def act(self, t_s: float, advisory: str) -> str:
        """Apply ``advisory`` at ``t_s``; what was done (``brake``, ``hold``, ``release``,
        ``none``)."""
        if not self.control.brake:
            return "none"
        if advisory == "brake":
            self._hold_until = t_s + self.control.hold_s
        if t_s < self._hold_until:
            carla = require_carla()
            if self.autopilot and not self.braking:
                self.ego.set_autopilot(False)
            steer = float(self.ego.get_control().steer)
            self.ego.apply_control(
                carla.VehicleControl(throttle=0.0, steer=steer, brake=self.control.brake_level)
            )
            done = "brake" if advisory == "brake" else "hold"
            self.braking = True
            return done
        if self.braking:
            self.braking = False
            if self.autopilot:
                self.ego.set_autopilot(True)
            else:
                carla = require_carla()
                self.ego.apply_control(carla.VehicleControl(throttle=0.0, brake=0.0))
            return "release"
        return "none"
