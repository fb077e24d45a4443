"""The backend: associate bearings, triangulate, track, and judge collision risk.

Library entry points (importable without click or rich):

- :func:`triangulate` / :func:`triangulate_batch`: emitter position and 2×2
  covariance from N ≥ 2 bearings, with an explicit status for bad geometry.
"""

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
    "FixStatus",
    "Triangulation",
    "TriangulationBatch",
    "TriangulationOptions",
    "bearing_crb",
    "triangulate",
    "triangulate_batch",
]
