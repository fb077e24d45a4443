"""The backend: associate bearings, triangulate, track, and judge collision risk.

Library entry points (importable without click or rich):

- :func:`triangulate` / :func:`triangulate_batch`: emitter position and 2×2
  covariance from N ≥ 2 bearings, with an explicit status for bad geometry.
- :func:`collision_probability`: probability that the vehicle's and the
  threat's boxes overlap (exact Owen's T integral or Lambert's Monte Carlo).
"""

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
from rfsas_hw.backend.triangulation import (
    FixStatus,
    Triangulation,
    TriangulationBatch,
    TriangulationOptions,
    bearing_crb,
    triangulate,
    triangulate_batch,
)

__all__ = [
    "THREAT_SIZES",
    "VEHICLE_SIGMA_ACROSS_M",
    "VEHICLE_SIGMA_ALONG_M",
    "VEHICLE_SIZE",
    "FixStatus",
    "MonteCarloEstimate",
    "Triangulation",
    "TriangulationBatch",
    "TriangulationOptions",
    "bearing_crb",
    "collision_probability",
    "collision_probability_batch",
    "collision_probability_mc",
    "heading_covariance",
    "threat_box",
    "triangulate",
    "triangulate_batch",
]
