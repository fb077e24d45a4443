"""Array bearings from CSI: every antenna of a CSI receiver in one all-element fit, and
the element calibration from frames at known angles.

A CSI frame carries the channel of every receive antenna on every stream
and subcarrier. Across a 20–40 MHz channel the plane-wave phase of a
palm-sized array changes by under 2 %, so each (stream, subcarrier) column
is a snapshot of the array; the common sampling-time ramp and the transmit
phase per column are the snapshot's unknown complex amplitude, which the fit
(:func:`~rfsas_hw.df.arrayfit.estimate_array`) absorbs. Thus every pair of
antennas contributes, not only the first.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.df.array import ArrayGeometry
from rfsas_hw.df.arraycal import ArrayCalibration
from rfsas_hw.df.arrayfit import estimate_array, fit_element_calibration
from rfsas_hw.df.calibration import Calibration
from rfsas_hw.df.estimate import DfFlag, DfResult
from rfsas_hw.errors import CalibrationError
from rfsas_hw.records import ObservationBatch


def csi_snapshots(h: npt.NDArray[np.complexfloating[Any, Any]]) -> npt.NDArray[np.complex128]:
    """CSI of shape (frames, antennas, streams, subcarriers) as array snapshots,
    shape (frames, streams·subcarriers, antennas)."""
    n, n_rx = h.shape[0], h.shape[1]
    out: npt.NDArray[np.complex128] = np.moveaxis(
        np.asarray(h, np.complex128).reshape(n, n_rx, -1), 1, 2
    )
    return out


def fit_array_calibration(
    geometry: ArrayGeometry,
    batch: ObservationBatch,
    theta_deg: npt.ArrayLike,
    fov_deg: tuple[float, float] | None = None,
) -> ArrayCalibration:
    """Each element's phase and gain from frames of a transmitter at known angles
    (``theta_deg``, degrees clockwise from boresight, one per frame), measured at the
    frames' carrier; every frame must be on the same frequency.

    Raises:
        CalibrationError: no CSI, a CSI antenna count that is not the array's, no
            frame, frames on more than one frequency or without one.
    """
    if batch.csi is None:
        raise CalibrationError("the frames carry no CSI or IQ samples")
    if batch.csi.h.shape[1] != geometry.n:
        raise CalibrationError(
            f"the array has {geometry.n} elements; the frames have {batch.csi.h.shape[1]} antennas"
        )
    freqs = np.unique(np.asarray(batch.freq_mhz))
    if len(freqs) != 1 or not freqs[0] > 0:
        raise CalibrationError(
            f"frames on {len(freqs)} frequencies ({', '.join(map(str, freqs[:5].tolist()))} MHz): "
            "calibrate on one known channel"
        )
    freq = float(freqs[0])
    elements = fit_element_calibration(geometry, csi_snapshots(batch.csi.h), theta_deg, freq)
    return ArrayCalibration(geometry, elements, freq, fov_deg)


def array_df_result(cal: Calibration, batch: ObservationBatch, mono: DfResult) -> DfResult:
    """The array's bearings of a CSI batch, in the monopulse's result shape.

    The SNR column and ``LOW_SNR`` flag are the monopulse's (the stronger
    antenna's RSSI); angle, σ and the other flags are the fit's. Frames
    without a frequency are flagged ``NO_TABLE``.

    Raises:
        CalibrationError: no ``array`` section, no CSI, or a CSI antenna count
            that is not the array's.
    """
    if cal.array is None:
        raise CalibrationError("the calibration has no array section")
    if batch.csi is None:
        raise CalibrationError("the observations carry no CSI (use a csi: source)")
    geometry = cal.array.geometry
    h = batch.csi.h
    n, n_rx = h.shape[0], h.shape[1]
    if n_rx != geometry.n:
        raise CalibrationError(f"the array has {geometry.n} elements; the CSI has {n_rx} antennas")
    snapshots = csi_snapshots(h)
    angle = np.full(n, np.nan, np.float32)
    sigma = np.full(n, np.nan, np.float32)
    flags = (mono.flags & np.uint8(DfFlag.LOW_SNR)).astype(np.uint8)
    freq = np.asarray(batch.freq_mhz)
    flags[~(freq > 0)] |= np.uint8(DfFlag.NO_TABLE)
    for f in np.unique(freq[freq > 0]).tolist():
        rows = freq == f
        res = estimate_array(
            geometry,
            snapshots[rows],
            float(f),
            calibration=cal.array.elements,
            fov_deg=cal.array.fov_deg,
        ).df
        angle[rows] = res.angle_deg
        sigma[rows] = res.sigma_deg
        flags[rows] |= res.flags
    bad = flags != 0
    angle[bad] = np.nan
    sigma[bad] = np.nan
    return DfResult(angle, sigma, mono.snr_db, flags)


def known_angle_errors_deg(
    cal: ArrayCalibration,
    batch: ObservationBatch,
    theta_deg: npt.ArrayLike,
    *,
    calibrated: bool = True,
) -> npt.NDArray[np.float64]:
    """Bearing error of each frame against its known angle, degrees (wrapped to ±180;
    NaN where the fit flagged the frame), with the element calibration applied or
    (``calibrated=False``) with ideal elements — to see what the calibration buys.

    Raises:
        CalibrationError: no CSI, or a CSI antenna count that is not the array's.
    """
    if batch.csi is None or batch.csi.h.shape[1] != cal.geometry.n:
        raise CalibrationError("the frames carry no CSI of the array's antennas")
    res = estimate_array(
        cal.geometry,
        csi_snapshots(batch.csi.h),
        cal.freq_mhz,
        calibration=cal.elements if calibrated else None,
        fov_deg=cal.fov_deg,
    ).df
    err = (np.asarray(res.angle_deg, np.float64) - np.asarray(theta_deg) + 180.0) % 360.0 - 180.0
    out: npt.NDArray[np.float64] = np.where(res.flags == 0, err, np.nan)
    return out
