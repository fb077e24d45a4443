"""RF-SAS overlays drawn on a simulator's own RGB frames.

The overlay draws, in pixels the adapter maps from the ground (rfsas frame):
the occluding buildings (outlines), every unit's bearing lines of the last
step (a ray of ``ray_m`` metres per emitter, newest bearing), and every
tracked emitter's two-sigma covariance ellipse, coloured by its advisory.

Drawing is plain numpy (points sampled along each line, half a pixel apart),
so it works on any ``(height, width, 3)`` ``uint8`` frame without a
graphics library.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt

from rfsas_hw.records import Assessment, BearingBatch, Pose
from rfsas_hw.twin.scenario import BuildingSpec

Array = npt.NDArray[np.float64]
Frame = npt.NDArray[np.uint8]
ToPixels = Callable[[Array, Array], "tuple[Array, Array] | None"]

BEARING_RGB = (0, 220, 230)
BUILDING_RGB = (90, 80, 70)
ADVISORY_RGB = {
    "brake": (230, 30, 30),
    "caution": (255, 170, 0),
    "clear": (40, 200, 60),
    "none": (200, 0, 200),
}
"""Ellipse colour per advisory."""
ELLIPSE_SIGMAS = 2.0
"""Ellipses are drawn at this many standard deviations."""

__all__ = ["ELLIPSE_SIGMAS", "draw_overlay", "draw_polyline", "ellipse_outline"]


def draw_polyline(
    frame: Frame, cols: Array, rows: Array, rgb: tuple[int, int, int], *, closed: bool = False
) -> int:
    """Draw the polyline through pixel points into ``frame`` (in place); pixels set."""
    if len(cols) < 2:
        return 0
    if closed:
        cols = np.append(cols, cols[0])
        rows = np.append(rows, rows[0])
    h, w = frame.shape[:2]
    pts_c: list[Array] = []
    pts_r: list[Array] = []
    for k in range(len(cols) - 1):
        c0, r0, c1, r1 = cols[k], rows[k], cols[k + 1], rows[k + 1]
        if not all(map(math.isfinite, (c0, r0, c1, r1))):
            continue
        n = int(min(max(abs(c1 - c0), abs(r1 - r0)) * 2.0, 8 * (w + h))) + 2
        t = np.linspace(0.0, 1.0, n)
        pts_c.append(c0 + (c1 - c0) * t)
        pts_r.append(r0 + (r1 - r0) * t)
    if not pts_c:
        return 0
    c = np.rint(np.concatenate(pts_c)).astype(np.int64)
    r = np.rint(np.concatenate(pts_r)).astype(np.int64)
    keep = (c >= 0) & (c < w) & (r >= 0) & (r < h)
    frame[r[keep], c[keep]] = rgb
    return int(keep.sum())


def ellipse_outline(
    x_m: float, y_m: float, cov: Array, sigmas: float = ELLIPSE_SIGMAS, n: int = 48
) -> tuple[Array, Array]:
    """Ground points (east, north; metres) of the ``sigmas`` ellipse of a 2×2 covariance."""
    c = np.where(np.isfinite(cov), cov, 0.0)
    w, v = np.linalg.eigh(0.5 * (c + c.T))
    axes = sigmas * np.sqrt(np.maximum(w, 0.0))
    a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    pts = (v * axes) @ np.stack([np.cos(a), np.sin(a)])
    return x_m + pts[0], y_m + pts[1]


def draw_overlay(
    frame: Frame,
    to_pixels: ToPixels,
    *,
    buildings: Sequence[BuildingSpec] = (),
    units: dict[str, Pose] | None = None,
    bearings: dict[str, BearingBatch] | None = None,
    assessments: Sequence[Assessment] = (),
    ray_m: float = 60.0,
) -> Frame:
    """A copy of ``frame`` with the RF-SAS picture drawn on it (see the module docstring).

    Args:
        frame: ``(height, width, 3)`` ``uint8`` image.
        to_pixels: maps rfsas-frame east/north arrays to pixel columns/rows (None: cannot).
        buildings: occluders to outline.
        units: unit poses by id (the start of each bearing ray).
        bearings: the last step's bearings per unit.
        assessments: tracked emitters.
        ray_m: length of a bearing ray, metres.
    """
    out = np.array(frame, dtype=np.uint8, copy=True)

    def line(east: Array, north: Array, rgb: tuple[int, int, int], closed: bool) -> None:
        px = to_pixels(np.asarray(east, np.float64), np.asarray(north, np.float64))
        if px is not None:
            draw_polyline(out, px[0], px[1], rgb, closed=closed)

    for b in buildings:
        line(
            np.array([b.x_min_m, b.x_max_m, b.x_max_m, b.x_min_m]),
            np.array([b.y_min_m, b.y_min_m, b.y_max_m, b.y_max_m]),
            BUILDING_RGB,
            True,
        )
    for uid, batch in (bearings or {}).items():
        pose = (units or {}).get(uid)
        if pose is None or not len(batch):
            continue
        newest: dict[int, float] = {}
        for i in np.argsort(batch.t_ns):
            newest[int(batch.emitter[i])] = float(batch.azimuth_deg[i])
        for az in newest.values():
            a = math.radians(az)
            line(
                np.array([pose.x_m, pose.x_m + ray_m * math.sin(a)]),
                np.array([pose.y_m, pose.y_m + ray_m * math.cos(a)]),
                BEARING_RGB,
                False,
            )
    for s in assessments:
        if not (math.isfinite(s.x_m) and math.isfinite(s.y_m)):
            continue
        east, north = ellipse_outline(s.x_m, s.y_m, s.covariance)
        line(east, north, ADVISORY_RGB.get(s.advisory, ADVISORY_RGB["none"]), True)
    return out
