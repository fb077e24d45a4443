"""RF-SAS on the test track: the two deployments and the device models of the matrix.

Deployments: ``car`` — the VUT's own unit only (boresight ahead); ``car+rsu``
— the VUT's unit plus one roadside unit at the crossing, on a pole on the
farside sidewalk 4 m past the crossing path and 7 m left of the VUT's lane
centre, looking back across the road at the nearside kerb (compass 200°),
so that it sees behind the parked vehicles from the other side of the road.
Devices: every target carries the same model, ``phone-active`` (a phone in
use) or ``phone-idle`` (probe bursts every 5 s); see
:data:`~rfsas_hw.bridges.config.DEVICE_MODELS`. Parked vehicles attenuate
the radio by their ``loss_db`` (:mod:`rfsas_hw.ncap.scenarios`). The backend
uses the ``urban-intersection-bearings`` profile (:mod:`rfsas_hw.bridges.config`):
the path rule, and tracks fed by each unit's bearing rather than by fixes, whose
acceptance test biases a standing person's track towards the lane (docs/ncap.md).

Both units carry the test track's environment floor (:data:`SITE_FLOOR_DEG`):
their turntable calibrations know free space only, so without it a bearing's
σ misses the multipath of the track and the tracker believes its fixes, and the
velocities it derives from them, more than they deserve.
"""

from __future__ import annotations

from typing import Literal

from rfsas_hw.bridges.config import BridgeConfig, EgoUnitSpec, KindDevices, UnitSpec
from rfsas_hw.ncap.scenarios import PATH_X_M, Obstacle
from rfsas_hw.twin.scenario import BuildingSpec, PoseSpec

Deployment = Literal["car", "car+rsu"]
DEPLOYMENTS: tuple[Deployment, ...] = ("car", "car+rsu")
DEVICES: tuple[str, ...] = ("phone-active", "phone-idle")
RSU_POSE = PoseSpec(x_m=PATH_X_M + 4.0, y_m=7.0, heading_deg=200.0)
"""The roadside unit's pose (see the module docstring). Its lines of bearing cross the VUT
unit's steeply, so fixes are accepted from about 20 m; a unit on the kerb looking along it
meets the VUT's lines almost parallel and its fixes are refused; its mirror image on the
nearside moves the nuisance brakes to the VUT's other side (docs/ncap.md, "Where the
roadside unit stands")."""
SITE_FLOOR_DEG = 3.0
"""Environment floor of both units' bearings on the test track, degrees: the angle
error beyond the calibration's σ model, measured as ``calibrate --check`` does
(:func:`~rfsas_hw.df.check.environment_floor_deg`) from the units' bearings against
the simulator's truth in true-negative and obstructed runs, bearings within 60° of
boresight: 3.1 and 4.2° for the roadside unit, 2.7 and 3.1° for the VUT's unit, in
two sets of runs (docs/ncap.md)."""

__all__ = ["DEPLOYMENTS", "DEVICES", "RSU_POSE", "SITE_FLOOR_DEG", "Deployment", "bridge_config"]


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
    units = (rsu,) if deployment == "car+rsu" else ()
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
