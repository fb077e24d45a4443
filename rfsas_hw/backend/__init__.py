"""The backend: associate bearings, triangulate, track, and judge collision risk.

Library entry points (importable without click or rich):

- :func:`triangulate` / :func:`triangulate_batch`: emitter position and 2×2
  covariance from N ≥ 2 bearings, with an explicit status for bad geometry.
- :func:`collision_probability`: probability that the vehicle's and the
  threat's boxes overlap (exact Owen's T integral or Lambert's Monte Carlo).
- :func:`impact_speed`, :func:`stopping_distance`, :func:`fatality_risk`,
  :func:`advise`: braking at 0.47 g, Rosen's P_f, the brake/caution/clear advisory.
- :class:`Associator`, :class:`Tracker`, :func:`assess_encounter`: the stages
  the :class:`BackendService` chains from verified messages to assessments.
"""

from rfsas_hw.backend.association import AssociationConfig, Associator, BearingGroups
from rfsas_hw.backend.collision import (
    THREAT_SIZES,
    VEHICLE_SIGMA_ACROSS_M,
    VEHICLE_SIGMA_ALONG_M,
    VEHICLE_SIZE,
    MonteCarloEstimate,
    collision_probability,
    collision_probability_batch,
    collision_probability_mc,
    heading_covariance,
    threat_box,
)
from rfsas_hw.backend.encounter import Encounter, EncounterConfig, assess_encounter
from rfsas_hw.backend.risk import (
    BRAKE_DECEL_MPS2,
    Advisory,
    AdvisoryThresholds,
    advise,
    fatality_risk,
    impact_speed,
    stopping_distance,
)
from rfsas_hw.backend.service import (
    BackendConfig,
    BackendService,
    BackendStats,
    JsonlSink,
    load_backend_config,
)
from rfsas_hw.backend.tracking import Track, Tracker, TrackerConfig
from rfsas_hw.backend.triangulation import (
    FixStatus,
    Triangulation,
    TriangulationBatch,
    TriangulationOptions,
    bearing_crb,
    triangulate,
    triangulate_batch,
)
from rfsas_hw.backend.vehicle import VehicleFeed, VehicleState, load_vehicle

__all__ = [
    "BRAKE_DECEL_MPS2",
    "THREAT_SIZES",
    "VEHICLE_SIGMA_ACROSS_M",
    "VEHICLE_SIGMA_ALONG_M",
    "VEHICLE_SIZE",
    "Advisory",
    "AdvisoryThresholds",
    "AssociationConfig",
    "Associator",
    "BackendConfig",
    "BackendService",
    "BackendStats",
    "BearingGroups",
    "Encounter",
    "EncounterConfig",
    "FixStatus",
    "JsonlSink",
    "MonteCarloEstimate",
    "Track",
    "Tracker",
    "TrackerConfig",
    "Triangulation",
    "TriangulationBatch",
    "TriangulationOptions",
    "VehicleFeed",
    "VehicleState",
    "advise",
    "assess_encounter",
    "bearing_crb",
    "collision_probability",
    "collision_probability_batch",
    "collision_probability_mc",
    "fatality_risk",
    "heading_covariance",
    "impact_speed",
    "load_backend_config",
    "load_vehicle",
    "stopping_distance",
    "threat_box",
    "triangulate",
    "triangulate_batch",
]
