"""Helpers shared by backend tests (put on the path by conftest.py)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from rfsas_hw.angles import math_rad_to_compass
from rfsas_hw.records import BearingBatch, Pose


def bearing_towards(
    sensor_id: str, pose: Pose, target_xy: npt.ArrayLike, emitter: int, t_ns: int
) -> BearingBatch:
    """One bearing from ``pose`` towards ``target_xy`` (metres east, north), exact,
    σ 1°, SNR 20 dB, channel 11."""
    d = np.asarray(target_xy, np.float64) - np.array([pose.x_m, pose.y_m])
    az = float(math_rad_to_compass(np.arctan2(d[1], d[0])))
    return BearingBatch(
        sensor_id,
        np.array([t_ns], np.int64),
        np.array([az]),
        np.array([1.0]),
        np.array([20.0]),
        np.array([11], np.int16),
        np.array([emitter], np.uint64),
    )


def one_bearing(
    sensor_id: str, t_ns: int, azimuth_deg: float, sigma_deg: float, emitter: int
) -> BearingBatch:
    """One bearing as measured: ``azimuth_deg`` (compass degrees) with ``sigma_deg``,
    SNR 20 dB, channel 6."""
    return BearingBatch(
        sensor_id=sensor_id,
        t_ns=np.array([t_ns], np.int64),
        azimuth_deg=np.array([azimuth_deg]),
        sigma_deg=np.array([sigma_deg]),
        snr_db=np.array([20.0]),
        channel=np.array([6], np.int16),
        emitter=np.array([emitter], np.uint64),
    )
