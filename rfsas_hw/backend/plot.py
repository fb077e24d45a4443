"""A map of the scene as a PNG: sensors, emitters with covariance ellipses, the vehicle.

Needs matplotlib (the ``plot`` extra), imported only when a map is drawn.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.errors import BackendError
from rfsas_hw.outpaths import save_figure
from rfsas_hw.records import Assessment, Fix, Pose

__all__ = ["ellipse_axes", "plot_map"]

INSTALL_HINT = "pip install 'rfsas-hw[plot]'"

ADVISORY_COLOURS = {"brake": "tab:red", "caution": "tab:orange", "clear": "tab:green"}


def ellipse_axes(cov: npt.ArrayLike, k: float = 2.0) -> tuple[float, float, float]:
    """Full width and height of the ``k``-sigma ellipse of a 2×2 covariance, and its angle.

    Returns:
        ``(width_m, height_m, angle_deg)``: the major axis length, the minor axis
        length, and the major axis direction in degrees counter-clockwise from east
        (matplotlib's convention).

    Raises:
        BackendError: not a finite symmetric 2×2 matrix.
    """
    c = np.asarray(cov, np.float64)
    if c.shape != (2, 2) or not np.isfinite(c).all():
        raise BackendError(f"covariance must be a finite 2×2 matrix, got {c.tolist()}")
    w, v = np.linalg.eigh((c + c.T) / 2)
    w = np.maximum(w, 0.0)
    major = v[:, 1]
    angle = math.degrees(math.atan2(major[1], major[0]))
    return 2 * k * math.sqrt(w[1]), 2 * k * math.sqrt(w[0]), angle


def _pyplot() -> Any:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as err:
        raise BackendError(f"drawing a map needs matplotlib: {INSTALL_HINT}") from err
    return plt


def plot_map(
    path: str | Path,
    *,
    stations: Mapping[str, Pose],
    assessments: Iterable[Assessment] = (),
    fixes: Iterable[Fix] = (),
    vehicle: VehicleState | None = None,
    k_sigma: float = 2.0,
    title: str = "rfsas backend",
) -> Path:
    """Draw the scene and write it as a PNG.

    Tracked emitters (assessments) get their ``k_sigma`` ellipse, coloured by
    advisory; fixes that were flagged are marked with an ``x`` at their best
    position (when there is one); the vehicle is its box with its own ellipse.

    Raises:
        BackendError: matplotlib is missing (names the install command), or the
            file cannot be written.
    """
    plt = _pyplot()
    from matplotlib.patches import Ellipse, Polygon

    fig, ax = plt.subplots(figsize=(7, 7))
    try:
        for sid, pose in stations.items():
            ax.plot(pose.x_m, pose.y_m, marker="^", color="tab:blue", markersize=9)
            ax.annotate(sid, (pose.x_m, pose.y_m), textcoords="offset points", xytext=(5, 5))
        for a in assessments:
            if not (math.isfinite(a.x_m) and math.isfinite(a.y_m)):
                continue
            colour = ADVISORY_COLOURS.get(a.advisory, "tab:purple")
            ax.plot(a.x_m, a.y_m, marker="o", color=colour)
            if np.isfinite(a.covariance).all():
                w, h, ang = ellipse_axes(a.covariance, k_sigma)
                ax.add_patch(
                    Ellipse((a.x_m, a.y_m), w, h, angle=ang, fill=False, color=colour, lw=1.5)
                )
            label = a.emitter[:8]
            if math.isfinite(a.p_collision):
                label += f" P={a.p_collision:.2f}"
            ax.annotate(label, (a.x_m, a.y_m), textcoords="offset points", xytext=(5, -12))
        for f in fixes:
            if not f.ok and math.isfinite(f.x_m) and math.isfinite(f.y_m):
                ax.plot(f.x_m, f.y_m, marker="x", color="grey")
        if vehicle is not None:
            u = vehicle.direction
            n = np.array([-u[1], u[0]])
            half_l, half_w = vehicle.length_m / 2, vehicle.width_m / 2
            c = vehicle.position
            signs = ((1, 1), (-1, 1), (-1, -1), (1, -1))
            corners = [c + su * half_l * u + sn * half_w * n for su, sn in signs]
            ax.add_patch(Polygon(np.array(corners), closed=True, color="black", alpha=0.6))
            w, h, ang = ellipse_axes(vehicle.covariance, k_sigma)
            ax.add_patch(
                Ellipse(tuple(c), w, h, angle=ang, fill=False, color="black", ls="--", lw=1)
            )
            ax.arrow(c[0], c[1], 3 * u[0], 3 * u[1], head_width=0.8, color="black")
        ax.set_aspect("equal", adjustable="datalim")
        ax.autoscale_view()
        ax.grid(True, alpha=0.3)
        ax.set_xlabel("east (m)")
        ax.set_ylabel("north (m)")
        ax.set_title(f"{title} ({k_sigma:g}σ ellipses)")
        out = Path(path)
        return save_figure(fig, out, dpi=100)
    finally:
        plt.close(fig)
