"""Path loss models, dB, distances in metres.

Three models:

- ``table``: the two-ray ground-reflection asymptote used by the published
  link budget, ``PL(d) = 40·log10(d) + offset_db``. The published table
  implies ``offset_db = 10·log10(24) ≈ 13.802 dB`` (method.md §2).
- ``breakpoint``: free space below the breakpoint distance ``4·h_t·h_r/λ``
  and the physical two-ray asymptote ``40·log10(d) − 20·log10(h_t·h_r)``
  beyond it (continuous at the breakpoint up to a few dB, as in the
  textbook model).
- ``coherent``: the direct and the ground-bounce ray summed with their phase
  difference and a reflection coefficient of −1; it shows the fading
  nulls the other two smooth over.
"""

from __future__ import annotations

import math
from typing import Literal, overload

import numpy as np
import numpy.typing as npt

SPEED_OF_LIGHT_MPS = 299_792_458.0
TABLE_OFFSET_DB = 10.0 * math.log10(24.0)
"""Offset that reproduces the published link-budget table: PL(100 m) = 93.802 dB."""

PathLossModel = Literal["table", "breakpoint", "coherent"]
Array = npt.NDArray[np.float64]


def wavelength_m(freq_mhz: float) -> float:
    """Free-space wavelength in metres of a carrier at ``freq_mhz``."""
    return SPEED_OF_LIGHT_MPS / (freq_mhz * 1e6)


def _check_distance(d: Array) -> None:
    if np.any(~(d > 0)):
        raise ValueError("distance must be positive (metres)")


def _geometry(distance_m: float | Array, ht_m: float, hr_m: float) -> Array:
    """Distances as an array, after checking distances and antenna heights are positive."""
    if ht_m <= 0 or hr_m <= 0:
        raise ValueError("antenna heights must be positive (metres)")
    d = np.asarray(distance_m, dtype=np.float64)
    _check_distance(d)
    return d


def free_space_path_loss_db(distance_m: float | Array, freq_mhz: float) -> Array:
    """Friis free-space path loss, dB, for isotropic antennas.

    Raises:
        ValueError: a distance that is not positive.
    """
    d = np.asarray(distance_m, dtype=np.float64)
    _check_distance(d)
    return 20.0 * np.log10(4.0 * math.pi * d / wavelength_m(freq_mhz))


def two_ray_table_path_loss_db(
    distance_m: float | Array, offset_db: float = TABLE_OFFSET_DB
) -> Array:
    """The published two-ray asymptote ``40·log10(d) + offset_db``, dB.

    Raises:
        ValueError: a distance that is not positive.
    """
    d = np.asarray(distance_m, dtype=np.float64)
    _check_distance(d)
    return 40.0 * np.log10(d) + offset_db


def two_ray_breakpoint_path_loss_db(
    distance_m: float | Array, freq_mhz: float, ht_m: float = 1.0, hr_m: float = 1.0
) -> Array:
    """Free space below ``4·h_t·h_r/λ``, ``40·log10(d) − 20·log10(h_t·h_r)`` beyond, dB.

    Raises:
        ValueError: a distance or antenna height that is not positive.
    """
    d = _geometry(distance_m, ht_m, hr_m)
    breakpoint_m = 4.0 * ht_m * hr_m / wavelength_m(freq_mhz)
    far = 40.0 * np.log10(d) - 20.0 * np.log10(ht_m * hr_m)
    return np.where(d < breakpoint_m, free_space_path_loss_db(d, freq_mhz), far)


def two_ray_coherent_path_loss_db(
    distance_m: float | Array, freq_mhz: float, ht_m: float = 1.0, hr_m: float = 1.0
) -> Array:
    """Direct plus ground-reflected ray (reflection coefficient −1), summed coherently, dB.

    Raises:
        ValueError: a distance or antenna height that is not positive.
    """
    d = _geometry(distance_m, ht_m, hr_m)
    lam = wavelength_m(freq_mhz)
    d_direct = np.hypot(d, ht_m - hr_m)
    d_reflect = np.hypot(d, ht_m + hr_m)
    k = 2.0 * math.pi / lam
    field = np.exp(-1j * k * d_direct) / d_direct - np.exp(-1j * k * d_reflect) / d_reflect
    gain = (lam / (4.0 * math.pi)) ** 2 * np.abs(field) ** 2
    # exact nulls would be -inf dB; floor them far below any receiver's sensitivity
    return -10.0 * np.log10(np.maximum(gain, 1e-30))


@overload
def path_loss_db(
    distance_m: float,
    model: PathLossModel = ...,
    *,
    freq_mhz: float = ...,
    ht_m: float = ...,
    hr_m: float = ...,
    offset_db: float = ...,
) -> float: ...
@overload
def path_loss_db(
    distance_m: Array,
    model: PathLossModel = ...,
    *,
    freq_mhz: float = ...,
    ht_m: float = ...,
    hr_m: float = ...,
    offset_db: float = ...,
) -> Array: ...
def path_loss_db(
    distance_m: float | Array,
    model: PathLossModel = "table",
    *,
    freq_mhz: float = 2437.0,
    ht_m: float = 1.0,
    hr_m: float = 1.0,
    offset_db: float = TABLE_OFFSET_DB,
) -> float | Array:
    """Path loss in dB with the named model (see the module docstring).

    Raises:
        ValueError: unknown model, or a non-positive distance or height.
    """
    if model == "table":
        out = two_ray_table_path_loss_db(distance_m, offset_db)
    elif model == "breakpoint":
        out = two_ray_breakpoint_path_loss_db(distance_m, freq_mhz, ht_m, hr_m)
    elif model == "coherent":
        out = two_ray_coherent_path_loss_db(distance_m, freq_mhz, ht_m, hr_m)
    else:
        raise ValueError(f"unknown path-loss model {model!r}: use table, breakpoint or coherent")
    return out if isinstance(distance_m, np.ndarray) else float(out)
