"""An array's calibration: its geometry and each element's phase and gain, in the
``array:`` section of a calibration file (beside the amplitude tables).

::

    array:
      freq_mhz: 2440
      positions_m: [[x, y], ...]        # element k on row k, metres
      phase_deg: [0.0, 12.5, ...]       # what each chain adds, element 0 = 0
      gain_db: [0.0, -0.4, ...]
      residual_deg: 2.1                 # measured phase error left, one sigma
      fov_deg: [-180, 180]              # optional; a line array: within ±90°
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.df.array import ArrayGeometry
from rfsas_hw.errors import CalibrationError

Complex = npt.NDArray[np.complexfloating[Any, Any]]


@dataclass(frozen=True, slots=True)
class ElementCalibration:
    """Per-element phase and gain of an array's receive chains (element 0 is the reference)."""

    phase_rad: npt.NDArray[np.float64]
    """Phase each chain adds, rad (0 for element 0)."""
    gain_db: npt.NDArray[np.float64]
    """Gain each chain adds relative to element 0, dB."""
    residual_rad: float = 0.0
    """Measured one-sigma phase error per element left after calibration, rad."""

    def apply(self, snapshots: Complex) -> npt.NDArray[np.complex128]:
        """``snapshots`` (…, N) with each chain's phase and gain removed."""
        corr = np.exp(-1j * self.phase_rad) * 10.0 ** (-self.gain_db / 20.0)
        out: npt.NDArray[np.complex128] = np.asarray(snapshots, np.complex128) * corr
        return out


@dataclass(frozen=True, slots=True)
class ArrayCalibration:
    """An array's geometry, the frequency it was calibrated at, and its elements."""

    geometry: ArrayGeometry
    elements: ElementCalibration
    freq_mhz: float
    """Carrier the element phases were measured at, MHz."""
    fov_deg: tuple[float, float] | None = None
    """Field of view, degrees from boresight; None: the whole search range."""


def _floats(value: Any, where: str, n: int | None = None) -> npt.NDArray[np.float64]:
    if not isinstance(value, list) or not all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in value
    ):
        raise CalibrationError(f"{where}: expected a list of numbers")
    out = np.asarray(value, np.float64)
    if not np.all(np.isfinite(out)):
        raise CalibrationError(f"{where}: values must be finite")
    if n is not None and len(out) != n:
        raise CalibrationError(f"{where}: {len(out)} values for {n} elements")
    return out


def array_from_mapping(data: Any, where: str) -> ArrayCalibration:
    """Validate the ``array:`` section of a calibration file.

    Raises:
        CalibrationError: wrong shape, unknown or missing key, bad value (key named).
    """
    if not isinstance(data, Mapping):
        raise CalibrationError(f"{where}: expected a mapping")
    known = {"freq_mhz", "positions_m", "phase_deg", "gain_db", "residual_deg", "fov_deg"}
    unknown = set(data) - known
    if unknown:
        raise CalibrationError(f"{where}: unknown key {sorted(unknown)[0]!r}")
    for key in ("freq_mhz", "positions_m", "phase_deg", "gain_db"):
        if key not in data:
            raise CalibrationError(f"{where}: missing key {key!r}")
    freq = data["freq_mhz"]
    if not (isinstance(freq, int | float) and math.isfinite(freq) and 0 < freq < 100_000):
        raise CalibrationError(f"{where}.freq_mhz: {freq!r} is not a frequency in MHz")
    rows = data["positions_m"]
    if not isinstance(rows, list):
        raise CalibrationError(f"{where}.positions_m: expected a list of [x, y]")
    pos = [_floats(r, f"{where}.positions_m[{i}]", 2) for i, r in enumerate(rows)]
    try:
        geometry = ArrayGeometry(np.array(pos).reshape(-1, 2))
    except ValueError as err:
        raise CalibrationError(f"{where}.positions_m: {err}") from err
    phase = np.radians(_floats(data["phase_deg"], f"{where}.phase_deg", geometry.n))
    gain = _floats(data["gain_db"], f"{where}.gain_db", geometry.n)
    resid = data.get("residual_deg", 0.0)
    if not (isinstance(resid, int | float) and math.isfinite(resid) and resid >= 0):
        raise CalibrationError(f"{where}.residual_deg: must be a number ≥ 0 degrees")
    fov = None
    if "fov_deg" in data:
        lo, hi = _floats(data["fov_deg"], f"{where}.fov_deg", 2)
        if not -180.0 <= lo < hi <= 180.0:
            raise CalibrationError(f"{where}.fov_deg: [{lo:g}, {hi:g}] is not inside ±180°")
        fov = (float(lo), float(hi))
    elements = ElementCalibration(phase, gain, math.radians(float(resid)))
    return ArrayCalibration(geometry, elements, float(freq), fov)


def array_to_mapping(cal: ArrayCalibration) -> dict[str, Any]:
    """The ``array:`` section of a calibration file (plain types)."""
    out: dict[str, Any] = {
        "freq_mhz": float(cal.freq_mhz),
        "positions_m": [
            [round(float(x), 6), round(float(y), 6)] for x, y in cal.geometry.positions_m
        ],
        "phase_deg": [round(float(v), 4) for v in np.degrees(cal.elements.phase_rad)],
        "gain_db": [round(float(v), 4) for v in cal.elements.gain_db],
        "residual_deg": round(math.degrees(cal.elements.residual_rad), 4),
    }
    if cal.fov_deg is not None:
        out["fov_deg"] = [float(cal.fov_deg[0]), float(cal.fov_deg[1])]
    return out
