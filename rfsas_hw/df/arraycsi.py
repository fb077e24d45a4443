"""Array bearings from CSI: every antenna of a CSI receiver in one all-element fit.

A CSI frame carries the channel of every receive antenna on every stream
and subcarrier. Across a 20–40 MHz channel the plane-wave phase of a
palm-sized array changes by under 2 %, so each (stream, subcarrier) column
is a snapshot of the array; the common sampling-time ramp and the transmit
phase per column are the snapshot's unknown complex amplitude, which the fit
(:func:`~rfsas_hw.df.arrayfit.estimate_array`) absorbs. Thus every pair of
antennas contributes, not only the first.
"""

from __future__ import annotations

import numpy as np

from rfsas_hw.df.arrayfit import estimate_array
from rfsas_hw.df.calibration import Calibration
from rfsas_hw.df.estimate import DfFlag, DfResult
from rfsas_hw.errors import CalibrationError
from rfsas_hw.records import ObservationBatch


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
    # (n, antennas, streams, subcarriers) → (n, streams·subcarriers, antennas)
    snapshots = np.moveaxis(h.reshape(n, n_rx, -1), 1, 2)
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
