"""RF-SAS on the test track: the deployments and the device models of the matrix.

Deployments: ``car`` — the VUT's own unit only (boresight ahead); ``car+rsu``
— the VUT's unit plus one roadside unit at the crossing, on a pole on the
farside sidewalk 4 m past the crossing path and 7 m left of the VUT's lane
centre, looking back across the road at the nearside kerb (compass 200°),
so that it sees behind the parked vehicles from the other side of the road;
``car+2rsu`` (opt-in, not in the command's default) — both of those and a second
roadside unit on the nearside kerb 6 m past the crossing path, looking back
along the kerb (compass 270°), so that a target crossing the road moves
across its line of sight (:data:`KERB_RSU_POSE`).
Devices: every target carries the same model, ``phone-active`` (a phone in
use) or ``phone-idle`` (probe bursts every 5 s); see
:data:`~rfsas_hw.bridges.config.DEVICE_MODELS`. Parked vehicles attenuate
the radio by their ``loss_db`` (:mod:`rfsas_hw.ncap.scenarios`). The backend
uses the ``urban-intersection-bearings`` profile (:mod:`rfsas_hw.bridges.config`):
the path rule, and tracks fed by each unit's bearing rather than by fixes, whose
acceptance test biases a standing person's track towards the lane (docs/ncap.md).

Every unit carries the test track's environment floor (:data:`SITE_FLOOR_DEG`):
their turntable calibrations know free space only, so without it a bearing's
σ misses the multipath of the track and the tracker believes its fixes, and the
velocities it derives from them, more than they deserve.
"""

from __future__ import annotations

from typing import Literal

from rfsas_hw.bridges.config import BridgeConfig, EgoUnitSpec, KindDevices, UnitSpec
from rfsas_hw.ncap.scenarios import PATH_X_M, Obstacle
from rfsas_hw.twin.scenario import BuildingSpec, PoseSpec

Deployment = Literal["car", "car+rsu", "car+2rsu"]
DEPLOYMENTS: tuple[Deployment, ...] = ("car", "car+rsu", "car+2rsu")
DEVICES: tuple[str, ...] = ("phone-active", "phone-idle")
RSU_POSE = PoseSpec(x_m=PATH_X_M + 4.0, y_m=7.0, heading_deg=200.0)
"""The roadside unit's pose (see the module docstring). Its lines of bearing cross the VUT
unit's steeply, so fixes are accepted from about 20 m; a unit on the kerb looking along it
meets the VUT's lines almost parallel and its fixes are refused; its mirror image on the
nearside moves the nuisance brakes to the VUT's other side (docs/ncap.md, "Where the
roadside unit stands")."""
KERB_RSU_POSE = PoseSpec(x_m=PATH_X_M + 6.0, y_m=-3.5, heading_deg=270.0)
"""The second roadside unit of ``car+2rsu``: on the nearside kerb line, 1.75 m outside the
VUT's lane edge and 6 m past the crossing path, looking back along the kerb (270°) at the
oncoming VUT and the parked vehicles' fronts. A target crossing from behind them moves
across this unit's line of sight (about 257° from behind the parked car to 286° at the
VUT's lane edge), so its bearings place the target across the road, which the VUT's unit
and :data:`RSU_POSE` place only to ``range × bearing error``; with the VUT's unit alone its
lines are nearly parallel and its fixes are refused, and with ``RSU_POSE`` beside it they
cross at about 60–80°. Chosen by measurement over (10, −3.5) m, 270° and (12, −6) m, 285°:
the same obstructed cells and nuisance runs with RF-SAS + LOS, and RF-SAS alone green in
more obstructed cells at lower impact speeds (docs/ncap.md, "Two roadside units")."""
SITE_FLOOR_DEG = 3.0
"""Environment floor of every unit's bearings on the test track, degrees: the angle
error beyond the calibration's σ model, measured as ``calibrate --check`` does
(:func:`~rfsas_hw.df.check.environment_floor_deg`) from the units' bearings against
the simulator's truth in true-negative and obstructed runs, bearings within 60° of
boresight: 3.1 and 4.2° for the roadside unit, 2.7 and 3.1° for the VUT's unit, in
two sets of runs (docs/ncap.md). The kerb unit of ``car+2rsu`` carries the same; measured
for it the same way, 2.0 and 2.3°, which 3.0° covers."""

__all__ = [
    "DEPLOYMENTS",
    "DEVICES",
    "KERB_RSU_POSE",
    "RSU_POSE",
    "SITE_FLOOR_DEG",
    "Deployment",
    "bridge_config",
]


def bridge_config(
    deployment: Deployment, device: str, seed: int, obstacles: tuple[Obstacle, ...]
) -> BridgeConfig:
    """The bridge settings of one run.

    Raises:
        ValueError: an unknown deployment or device model.
    """
    if deployment not in DEPLOYMENTS:
        raise ValueError(f"unknown deployment {deployment!r} (known: {', '.join(DEPLOYMENTS)})")
    if device not in DEVICES:
        raise ValueError(f"unknown device model {device!r} (known: {', '.join(DEVICES)})")
    rsu = UnitSpec("rsu-crossing", RSU_POSE, env_floor_deg=SITE_FLOOR_DEG)
    kerb = UnitSpec("rsu-kerb", KERB_RSU_POSE, env_floor_deg=SITE_FLOOR_DEG)
    by_deployment: dict[str, tuple[UnitSpec, ...]] = {
        "car": (),
        "car+rsu": (rsu,),
        "car+2rsu": (rsu, kerb),
    }
    units = by_deployment[deployment]
    parked = tuple(
        BuildingSpec(o.x_min_m, o.x_max_m, o.y_min_m, o.y_max_m, name=o.name, loss_db=o.loss_db)
        for o in obstacles
    )
    return BridgeConfig(
        units=units,
        seed=seed,
        backend_profile="urban-intersection-bearings",
        ego_unit=EgoUnitSpec(id="vut-unit", env_floor_deg=SITE_FLOOR_DEG),
        buildings=parked,
        buildings_from_simulator=False,
        devices={
            "pedestrian": KindDevices(device, 1.0),
            "cyclist": KindDevices(device, 1.0),
            "vehicle": KindDevices(None, 0.0),
        },
    )
