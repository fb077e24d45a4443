"""Antenna array geometry: where the elements are, and the plane-wave phase at each.

Coordinates are metres in the array's own frame: ``y`` along boresight,
``x`` to its clockwise side (to the right, seen from behind the array). A
plane wave from azimuth θ (degrees clockwise from boresight, full circle)
travels toward the array from the unit vector ``u = (sin θ, cos θ)``; an
element at ``p`` sees it ``p·u / c`` seconds early, so its channel carries
the phase ::

    φ_k(θ) = 2π · (p_k · u) / λ

relative to the origin: the same sign as the interferometer's
``Δφ = 2π·(D/λ)·sin θ`` for a pair on the ``x`` axis
(:mod:`rfsas_hw.df.interferometer`). Element positions come from the
standard shapes (:meth:`ArrayGeometry.ula`, :meth:`~ArrayGeometry.uca`,
:meth:`~ArrayGeometry.ura`) or a CSV file of ``x_m,y_m`` rows
(:func:`load_geometry`).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import CalibrationError

Array = npt.NDArray[np.floating[Any]]
C_MPS = 299_792_458.0
MAX_ELEMENTS = 64
"""Most elements an array may have."""


@dataclass(frozen=True)
class ArrayGeometry:
    """Positions of an array's elements, metres (``x`` clockwise side, ``y`` boresight)."""

    positions_m: npt.NDArray[np.float64]
    """Element positions, shape (N, 2), metres; row k is element k."""
    name: str = "custom"
    """What the array is (``ula``, ``uca``, ``ura`` or ``custom``)."""

    def __post_init__(self) -> None:
        pos = np.asarray(self.positions_m, dtype=np.float64)
        if pos.ndim != 2 or pos.shape[1] != 2:
            raise ValueError(f"positions must have shape (N, 2), got {pos.shape}")
        if not 2 <= len(pos) <= MAX_ELEMENTS:
            raise ValueError(f"an array has 2…{MAX_ELEMENTS} elements, got {len(pos)}")
        if not np.all(np.isfinite(pos)):
            raise ValueError("element positions must be finite")
        gaps = np.linalg.norm(pos[:, None, :] - pos[None, :, :], axis=2)
        if np.any(gaps[np.triu_indices(len(pos), 1)] < 1e-4):
            raise ValueError("two elements closer than 0.1 mm: the same element twice?")
        object.__setattr__(self, "positions_m", pos - pos.mean(axis=0))

    @property
    def n(self) -> int:
        """Number of elements."""
        return len(self.positions_m)

    @property
    def collinear(self) -> bool:
        """True when all elements lie on one line: such an array cannot tell front from
        back (θ and its mirror across the line give the same phases)."""
        centred = self.positions_m
        return bool(np.linalg.matrix_rank(centred, tol=1e-6) < 2)

    @property
    def axis_deg(self) -> float:
        """For a collinear array, the azimuth its line points to, degrees (clockwise from
        boresight); NaN otherwise."""
        if not self.collinear:
            return math.nan
        _, _, vt = np.linalg.svd(self.positions_m)
        x, y = vt[0]
        return math.degrees(math.atan2(x, y))

    def phases_rad(self, theta_deg: npt.ArrayLike, freq_mhz: float) -> Array:
        """Plane-wave phase of each element, rad, shape ``(..., N)`` for angles ``(...)``."""
        theta = np.radians(np.asarray(theta_deg, dtype=np.float64))[..., None]
        k = 2.0 * math.pi * freq_mhz * 1e6 / C_MPS
        x, y = self.positions_m[:, 0], self.positions_m[:, 1]
        out: Array = k * (x * np.sin(theta) + y * np.cos(theta))
        return out

    def steering(self, theta_deg: npt.ArrayLike, freq_mhz: float) -> npt.NDArray[np.complex128]:
        """Unit-magnitude steering vectors ``exp(j·φ_k(θ))``, shape ``(..., N)``."""
        out: npt.NDArray[np.complex128] = np.exp(1j * self.phases_rad(theta_deg, freq_mhz))
        return out

    def steering_derivative(
        self, theta_deg: npt.ArrayLike, freq_mhz: float
    ) -> npt.NDArray[np.complex128]:
        """d(steering)/dθ per radian of θ, shape ``(..., N)``."""
        theta = np.radians(np.asarray(theta_deg, dtype=np.float64))[..., None]
        k = 2.0 * math.pi * freq_mhz * 1e6 / C_MPS
        x, y = self.positions_m[:, 0], self.positions_m[:, 1]
        dphi = k * (x * np.cos(theta) - y * np.sin(theta))
        out: npt.NDArray[np.complex128] = 1j * dphi * self.steering(theta_deg, freq_mhz)
        return out

    @classmethod
    def ula(cls, n: int, spacing_m: float) -> ArrayGeometry:
        """``n`` elements on the ``x`` axis, ``spacing_m`` apart (boresight broadside).

        Raises:
            ValueError: fewer than 2 elements or a spacing that is not positive.
        """
        if not spacing_m > 0:
            raise ValueError(f"ULA spacing must be positive, got {spacing_m} m")
        x = (np.arange(n) - (n - 1) / 2) * spacing_m
        return cls(np.column_stack([x, np.zeros(n)]), "ula")

    @classmethod
    def uca(cls, n: int, radius_m: float) -> ArrayGeometry:
        """``n`` elements evenly on a circle of ``radius_m``, element 0 on boresight.

        Raises:
            ValueError: fewer than 3 elements or a radius that is not positive.
        """
        if n < 3 or not radius_m > 0:
            raise ValueError(f"a UCA needs ≥ 3 elements and a positive radius, got {n}, {radius_m}")
        a = 2.0 * math.pi * np.arange(n) / n
        return cls(radius_m * np.column_stack([np.sin(a), np.cos(a)]), "uca")

    @classmethod
    def ura(cls, nx: int, ny: int, dx_m: float, dy_m: float) -> ArrayGeometry:
        """A rectangular grid of ``nx`` × ``ny`` elements in the horizontal plane,
        ``dx_m`` across boresight and ``dy_m`` along it.

        Raises:
            ValueError: a side under 1 element or a spacing that is not positive.
        """
        if nx < 1 or ny < 1 or not (dx_m > 0 and dy_m > 0):
            raise ValueError("a URA needs ≥ 1 element per side and positive spacings")
        gx, gy = np.meshgrid(np.arange(nx) * dx_m, np.arange(ny) * dy_m, indexing="xy")
        return cls(np.column_stack([gx.ravel(), gy.ravel()]), "ura")


def load_geometry(path: str | Path) -> ArrayGeometry:
    """Element positions from a CSV file with a header ``x_m,y_m`` and one row per element.

    Raises:
        CalibrationError: unreadable file, missing columns, a value that is not a
            number (file and line named) or an impossible array.
    """
    p = Path(path)
    try:
        with p.open(newline="", encoding="utf-8") as f:
            rows = list(csv.DictReader(f))
            header = rows[0].keys() if rows else set()
    except (OSError, UnicodeDecodeError) as err:
        raise CalibrationError(f"{p}: cannot read element positions: {err}") from err
    if not {"x_m", "y_m"} <= set(header):
        raise CalibrationError(f"{p}: needs a header with x_m and y_m and one row per element")
    pos = []
    for line, row in enumerate(rows, start=2):
        try:
            pos.append((float(row["x_m"]), float(row["y_m"])))
        except (TypeError, ValueError) as err:
            raise CalibrationError(f"{p}: line {line}: x_m, y_m must be numbers ({err})") from err
    try:
        return ArrayGeometry(np.array(pos), "custom")
    except ValueError as err:
        raise CalibrationError(f"{p}: {err}") from err
