"""MetaDrive (PGDrive's successor): an RF-SAS sensor and a manager of crossers.

MetaDrive (the ``metadrive`` extra) pulls the ``pygame`` distribution, which
clashes with the ``pygame-ce`` that highway-env needs, so it lives in a
virtual environment of its own (``make metadrive`` builds
``.venv-metadrive`` and runs its tests there).

**Physics only.** MetaDrive downloads ``assets.zip`` (models, textures) from
GitHub on the first ``reset()``. Without network access it cannot; but a run
without rendering (``use_render=False``, no image observation) needs no asset
at all, only the folder's ``version.txt`` (and the grass texture's file name,
which MetaDrive checks to decide whether its assets are outdated).
:func:`write_stub_assets` writes exactly those two files when the folder is
missing, and never touches real assets; :func:`asset_problem` says what is
missing. Rendering is not available with the stub.

The pieces, in MetaDrive's own terms:

- :class:`CrosserManager` (a MetaDrive ``BaseManager``, registered as
  ``rfsas_crossers``): spawns the planned pedestrians (``Pedestrian``) and
  cyclists (``Cyclist``) and moves them along their straight crossing paths
  each step (position set to the plan's after each physics step, velocity
  set for the next, so Bullet sees the contact and MetaDrive reports
  ``crash_human``);
- :class:`RfsasSensor` (a MetaDrive ``BaseSensor``, registered in the env's
  ``sensors`` config as ``rfsas``): ``perceive(ego)`` reads the ego, every
  vehicle and every traffic participant in the rfsas frame
  (:data:`~rfsas_hw.bridges.coords.FRAMES` ``["metadrive"]``: ``y`` north,
  ``heading_theta`` counter-clockwise from east);
- :class:`MetaDriveAdapter` for :class:`~rfsas_hw.envs.rfsas_wrapper.RfsasWrapper`:
  plans the crossing on the ego's lane (:func:`~rfsas_hw.bridges.crossing.plan_crossing`),
  hands it to the manager, reads through the sensor, brakes with
  ``[steering, -1]``.

The default scene (:func:`make_scene`) is a straight road (``map="S"``), no
traffic, the ego starting at 10 m/s; the crossing is 35 m ahead. MetaDrive
has no buildings here: the occluder exists for the radio (the bridge
attenuates paths through it), while MetaDrive's lidar sees the crossers
unobstructed — which matters only to a policy that reads the lidar.
"""

from __future__ import annotations

import importlib
import importlib.util
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.bridges.adapter import Array, Snapshot
from rfsas_hw.bridges.bridge import Entity
from rfsas_hw.bridges.config import EntityKind, UnitSpec
from rfsas_hw.bridges.coords import FRAMES
from rfsas_hw.bridges.crossing import CrossingConfig, CrossingPlan, plan_crossing
from rfsas_hw.errors import MissingDependencyError, SimulationError
from rfsas_hw.twin.scenario import BuildingSpec

FRAME = FRAMES["metadrive"]
MANAGER_NAME = "rfsas_crossers"
"""Name of the crosser manager in the MetaDrive engine."""
SENSOR_NAME = "rfsas"
"""Name of the RF-SAS sensor in the env's ``sensors`` config."""
GRASS_TEXTURE = ("textures", "grass1", "GroundGrassGreen002_COL_1K.jpg")
"""The file MetaDrive checks to decide whether its assets are outdated."""
INSTALL = "make metadrive (its own virtual environment: .venv-metadrive)"

__all__ = [
    "MANAGER_NAME",
    "SENSOR_NAME",
    "MetaDriveAdapter",
    "asset_problem",
    "cruise_action",
    "make_scene",
    "require_metadrive",
    "write_stub_assets",
]


def _assets_dir() -> Path:
    spec = importlib.util.find_spec("metadrive")
    if spec is None or spec.origin is None:
        raise MissingDependencyError(f"MetaDrive is not installed; install it with: {INSTALL}")
    return Path(spec.origin).parent / "assets"


def asset_problem() -> str | None:
    """What keeps MetaDrive from starting without a download, or None when it can start.

    Raises:
        MissingDependencyError: MetaDrive is not installed.
    """
    assets = _assets_dir()
    version = assets / "version.txt"
    if not version.is_file():
        return (
            f"MetaDrive's assets are missing ({version} does not exist): its first reset "
            "would download assets.zip from GitHub; write the physics-only stub with "
            "write_stub_assets() (make metadrive does)"
        )
    if not assets.joinpath(*GRASS_TEXTURE).exists():
        return (
            f"MetaDrive would call its assets outdated and download them again: "
            f"{assets.joinpath(*GRASS_TEXTURE)} is missing"
        )
    return None


def write_stub_assets() -> Path:
    """Write the physics-only stub (``version.txt`` and the grass texture's name) into
    MetaDrive's asset folder when it has no assets; return the folder.

    Real assets (a ``version.txt`` already there) are left alone.

    Raises:
        MissingDependencyError: MetaDrive is not installed.
    """
    assets = _assets_dir()
    if (assets / "version.txt").is_file():
        return assets
    version = importlib.import_module("metadrive.version").VERSION
    texture = assets.joinpath(*GRASS_TEXTURE)
    texture.parent.mkdir(parents=True, exist_ok=True)
    texture.touch()
    (assets / "version.txt").write_text(f"{version}\n", encoding="utf-8")
    return assets


def require_metadrive() -> Any:
    """The ``metadrive`` module, ready for a physics-only run.

    Raises:
        MissingDependencyError: MetaDrive is not installed, or its assets (or the stub)
            are missing — the message says which file.
    """
    try:
        md = importlib.import_module("metadrive")
    except ImportError as err:
        raise MissingDependencyError(
            f"MetaDrive is not installed; install it with: {INSTALL}"
        ) from err
    problem = asset_problem()
    if problem is not None:
        raise MissingDependencyError(problem)
    return md


@cache
def _classes() -> dict[str, type]:
    """MetaDrive subclasses, defined once MetaDrive is importable."""
    require_metadrive()
    from metadrive.component.sensors.base_sensor import BaseSensor
    from metadrive.component.traffic_participants.cyclist import Cyclist
    from metadrive.component.traffic_participants.pedestrian import Pedestrian
    from metadrive.component.vehicle.base_vehicle import BaseVehicle
    from metadrive.envs.metadrive_env import MetaDriveEnv
    from metadrive.manager.base_manager import BaseManager

    def step_s(engine: Any) -> float:
        cfg = engine.global_config
        return float(cfg["physics_world_step_size"]) * int(cfg["decision_repeat"])

    class CrosserManager(BaseManager):
        """Spawns the planned crossers and moves them along their paths."""

        PRIORITY = 20

        def __init__(self) -> None:
            super().__init__()
            self.plans: dict[str, Any] = {}

        def before_reset(self) -> None:
            super().before_reset()
            self.plans = {}

        def spawn(self, crossers: tuple[Any, ...]) -> None:
            for cr in crossers:
                cls = Cyclist if cr.kind == "cyclist" else Pedestrian
                obj = self.spawn_object(
                    cls,
                    position=[float(v) for v in cr.position(0.0)],
                    heading_theta=cr.heading_rad,
                    name=cr.id,
                    random_seed=0,
                )
                direction = cr.velocity_xy / max(cr.speed_mps, 1e-9)
                obj.set_velocity([float(direction[0]), float(direction[1])], cr.speed_mps)
                self.plans[cr.id] = cr

        def after_step(self, *args: Any, **kwargs: Any) -> dict[str, Any]:
            # each crosser is put where its plan says after every physics step (so what the
            # sensor reads is exact) and given its velocity for the next one (so Bullet
            # sees it move into a contact)
            t = self.engine.episode_step * step_s(self.engine)
            gone = []
            for name, obj in list(self.spawned_objects.items()):
                cr = self.plans.get(name)
                if cr is None:
                    continue
                if t >= cr.exit_s:
                    gone.append(name)
                    continue
                obj.set_position([float(v) for v in cr.position(t)])
                obj.set_heading_theta(cr.heading_rad)
                direction = cr.velocity_xy / max(cr.speed_mps, 1e-9)
                obj.set_velocity([float(direction[0]), float(direction[1])], cr.speed_mps)
            if gone:
                self.clear_objects(gone)
                for name in gone:
                    self.plans.pop(name, None)
            return {}

    class RfsasSensor(BaseSensor):
        """Reads the ego, the vehicles and the traffic participants in the rfsas frame."""

        def __init__(self, engine: Any) -> None:
            self.engine = engine
            self._ids: dict[str, str] = {}

        def _id(self, obj: Any) -> str:
            if obj.name in self._ids:
                return self._ids[obj.name]
            eid = f"vehicle-{len(self._ids)}"
            self._ids[obj.name] = eid
            return eid

        def perceive(self, ego: Any, *args: Any, **kwargs: Any) -> Snapshot:
            t = self.engine.episode_step * step_s(self.engine)
            others = []
            for obj in self.engine.get_objects().values():
                if obj is ego:
                    continue
                if isinstance(obj, Pedestrian):
                    kind: EntityKind = "pedestrian"
                    eid = str(obj.name)
                elif isinstance(obj, Cyclist):
                    kind, eid = "cyclist", str(obj.name)
                elif isinstance(obj, BaseVehicle):
                    kind, eid = "vehicle", self._id(obj)
                else:
                    continue
                others.append(_entity(eid, kind, obj))
            return Snapshot(float(t), _entity("ego", "vehicle", ego), tuple(others))

        def destroy(self) -> None:
            self._ids = {}

    class RfsasMetaDriveEnv(MetaDriveEnv):
        """MetaDrive with the crosser manager and the RF-SAS sensor."""

        def reset(self, seed: int | None = None) -> Any:
            # MetaDrive's seed picks the scenario; Gymnasium's own generator is seeded too
            # (MetaDrive does not call Env.reset), as Gymnasium's checker expects
            gym_reset = importlib.import_module("gymnasium").Env.reset
            gym_reset(self, seed=seed)
            if seed is not None:
                cfg = self.config
                seed = int(cfg["start_seed"]) + seed % int(cfg["num_scenarios"])
            return super().reset(seed=seed)

        @classmethod
        def default_config(cls) -> Any:
            cfg = super().default_config()
            cfg["sensors"][SENSOR_NAME] = (RfsasSensor,)
            return cfg

        def setup_engine(self) -> None:
            super().setup_engine()
            self.engine.register_manager(MANAGER_NAME, CrosserManager())

    return {
        "CrosserManager": CrosserManager,
        "RfsasSensor": RfsasSensor,
        "RfsasMetaDriveEnv": RfsasMetaDriveEnv,
    }


def _entity(eid: str, kind: EntityKind, obj: Any) -> Entity:
    x, y = obj.position
    return Entity.from_sim(
        FRAME,
        eid,
        kind,
        (float(x), float(y)),
        float(obj.heading_theta),
        speed_mps=obj.speed,
        length_m=obj.LENGTH,
        width_m=obj.WIDTH,
    )


SCENE_DEFAULTS: dict[str, Any] = {
    "use_render": False,
    "image_observation": False,
    "map": "S",
    "num_scenarios": 1,
    "start_seed": 0,
    "traffic_density": 0.0,
    "horizon": 100,
    "log_level": 50,
    "vehicle_config": {"spawn_velocity": [10.0, 0.0]},
}
"""The default scene: a straight road, no traffic, the ego at 10 m/s, 10 s at most."""


def make_scene(config: dict[str, Any] | None = None) -> Any:
    """MetaDrive with the crosser manager and the RF-SAS sensor (``SCENE_DEFAULTS``
    updated by ``config``).

    Raises:
        MissingDependencyError: MetaDrive or its assets are missing (says which file).
    """
    env_cls = _classes()["RfsasMetaDriveEnv"]
    cfg = {**SCENE_DEFAULTS, **(config or {})}
    return env_cls(cfg)


def cruise_action(env: Any, target_mps: float = 10.0, gain: float = 0.5) -> npt.NDArray[np.float32]:
    """Straight ahead at ``target_mps``: throttle or brake proportional to the speed error."""
    speed = float(env.unwrapped.agent.speed)
    return np.array([0.0, float(np.clip(gain * (target_mps - speed), -1.0, 1.0))], np.float32)


class MetaDriveAdapter:
    """RF-SAS for a MetaDrive scene made by :func:`make_scene` (see the module docstring).

    Args:
        crossing: the crossers (default: one, 35 m ahead of the ego).
    """

    frame_name = "metadrive"

    def __init__(self, crossing: CrossingConfig | None = None) -> None:
        self.crossing = crossing or CrossingConfig(ahead_m=35.0, min_ahead_m=35.0)
        self.plan: CrossingPlan | None = None

    def env_seed(self, env: Any, seed: int) -> int:
        """``seed`` itself: the env seeds Gymnasium's generator with it and picks MetaDrive's
        scenario ``start_seed + seed % num_scenarios``."""
        return seed

    def reset(self, env: Any, seed: int) -> None:
        """Plan the crossing on the ego's lane and spawn the crossers.

        Raises:
            SimulationError: the env has no crosser manager (not made by :func:`make_scene`).
        """
        base = env.unwrapped
        managers = base.engine.managers
        if MANAGER_NAME not in managers:
            raise SimulationError(
                "MetaDrive: the env has no crosser manager; make it with "
                "rfsas_hw.bridges.metadrive.make_scene()"
            )
        ego = base.agent
        self.plan = plan_crossing(
            ego.lane, np.asarray(ego.position), float(ego.speed), FRAME, self.crossing, seed
        )
        managers[MANAGER_NAME].spawn(self.plan.crossers)

    def after_step(self, env: Any) -> None:
        """Nothing: the manager moves the crossers inside MetaDrive's step."""

    def read(self, env: Any) -> Snapshot:
        """The ego and everyone else, through the RF-SAS sensor."""
        base = env.unwrapped
        snap: Snapshot = base.engine.get_sensor(SENSOR_NAME).perceive(base.agent)
        return snap

    def buildings(self) -> list[BuildingSpec]:
        """The occluder (radio only: MetaDrive has no building here)."""
        return [] if self.plan is None else [self.plan.building]

    def units(self) -> list[UnitSpec]:
        """The two roadside units of this episode."""
        return [] if self.plan is None else list(self.plan.units)

    def brake_action(self, env: Any, action: Any) -> npt.NDArray[np.float32]:
        """``[steering, -1]``: the agent's steering, full brake."""
        out = np.array(action, dtype=np.float32, copy=True).reshape(-1)
        out[1] = -1.0
        return out

    def collided(self, env: Any, info: dict[str, Any]) -> bool:
        """Whether MetaDrive reports a crash (with a person, a vehicle or an object)."""
        return bool(info.get("crash", False) or info.get("crash_human", False))

    def bounded_space(self, env: Any) -> Any:
        """None: MetaDrive declares its observation bounds."""
        return None

    def to_pixels(self, env: Any, east_m: Array, north_m: Array) -> tuple[Array, Array] | None:
        """None: a physics-only run has no frames."""
        return None
