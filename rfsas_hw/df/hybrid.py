"""Interferometer bearings of CSI observations, their branch chosen by the amplitude monopulse.

:func:`estimate_phase` takes an :class:`~rfsas_hw.records.ObservationBatch`
with CSI and a :class:`~rfsas_hw.df.calibration.Calibration` holding a
``phase`` section: the first pair's calibrated offset and chain delay are
removed per channel, the per-chain SNR comes from the RSSI against the
calibration's noise floor, and — for a baseline over λ/2 — the monopulse
angle from the same frame's RSSI (antennas 0 and 1, the amplitude tables)
picks the phase branch.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from rfsas_hw.df.calibration import Calibration
from rfsas_hw.df.estimate import DfFlag, DfResult, estimate
from rfsas_hw.df.fovrule import near_edge
from rfsas_hw.df.interferometer import (
    IfFlag,
    InterferometerResult,
    bearings,
    effective_snr_db,
    pair_phase,
)
from rfsas_hw.errors import CalibrationError
from rfsas_hw.records import ObservationBatch, ObsFlag
from rfsas_hw.rf.aoa import PhaseForm


def estimate_phase(
    cal: Calibration,
    batch: ObservationBatch,
    *,
    hybrid: bool = True,
    form: PhaseForm = "textbook",
    mono: DfResult | None = None,
) -> tuple[InterferometerResult, npt.NDArray[np.float64]]:
    """Interferometer angle, σ and flags per frame, and the per-frame SNR of the pair, dB.

    Frames whose channel has no phase offset are flagged ``NO_TABLE``; frames the
    source flagged ``PHASE_AMBIGUOUS`` (Intel 5300 at 2.4 GHz) ``AMBIGUOUS``.
    With ``hybrid`` the monopulse angle (where valid) chooses the branch;
    ``mono`` is that monopulse result when the caller already has it for
    these frames (else it is computed here).

    Raises:
        CalibrationError: the calibration has no ``phase`` section, or the
            batch carries no CSI or too few antennas for the pair.
    """
    if cal.phase is None:
        raise CalibrationError("the calibration has no phase section (rfsas calibrate --phase)")
    if batch.csi is None:
        raise CalibrationError("the observations carry no CSI (use a csi: source)")
    pair = cal.phase.pairs[0]
    n = len(batch)
    if max(pair.a, pair.b) >= batch.csi.h.shape[1]:
        raise CalibrationError(
            f"phase pair ({pair.a}, {pair.b}) needs {max(pair.a, pair.b) + 1} antennas; "
            f"the CSI has {batch.csi.h.shape[1]}"
        )
    offset = np.zeros(n)
    delay = np.zeros(n)
    resid = np.zeros(n)
    no_table = np.zeros(n, bool)
    for ch in np.unique(batch.channel):
        rows = batch.channel == ch
        entry = pair.offset_for(int(ch))
        if entry is None:
            no_table |= rows
            continue
        offset[rows] = math.radians(entry.offset_deg)
        delay[rows] = entry.delay_ns
        resid[rows] = entry.residual_deg
    phase = pair_phase(batch.csi, pair.a, pair.b, offset_rad=offset, delay_ns=delay)
    rssi = batch.rssi_dbm.astype(np.float64)
    snr_chain = rssi - cal.noise_floor_dbm
    cols = [pair.a, pair.b]
    if rssi.shape[1] > max(cols):
        snr = effective_snr_db(snr_chain[:, cols[0]], snr_chain[:, cols[1]], phase.terms)
    else:
        snr = np.full(n, np.nan)
    hint = hint_sigma = None
    if hybrid and rssi.shape[1] >= 2:
        if mono is None:
            mono = estimate(cal, rssi[:, 0], rssi[:, 1], batch.channel)
        hint = np.where(mono.valid, mono.angle_deg, np.nan)
        hint_sigma = np.where(mono.valid, mono.sigma_deg, np.nan)
    result = bearings(
        phase,
        batch.freq_mhz,
        pair.baseline_m,
        snr_db=np.where(np.isfinite(snr), snr, np.nan),
        residual_deg=resid,
        fov_deg=cal.phase.fov_deg,
        hint_deg=hint,
        hint_sigma_deg=hint_sigma,
        form=form,
    )
    if no_table.any():
        result.flags[no_table] |= np.uint8(IfFlag.NO_TABLE)
        result.angle_deg[no_table] = np.nan
        result.sigma_deg[no_table] = np.nan
    # the Intel 5300's per-chain phase at 2.4 GHz may be off by kπ/2: no bearing from it
    unsure = (batch.flags & np.uint16(ObsFlag.PHASE_AMBIGUOUS)) != 0
    if unsure.any():
        result.flags[unsure] |= np.uint8(IfFlag.AMBIGUOUS)
        result.angle_deg[unsure] = np.nan
        result.sigma_deg[unsure] = np.nan
    return result, snr


def phase_df_result(cal: Calibration, batch: ObservationBatch, mono: DfResult) -> DfResult:
    """The interferometer's bearings in the monopulse's result shape (for the sensor pipeline).

    Angle and σ come from :func:`estimate_phase`; the SNR column and a
    ``LOW_SNR`` flag are the monopulse's (the stronger antenna's RSSI). A
    saturated RSSI does not reject a phase bearing. ``mono`` also picks the
    interferometer's branch (its ``LOW_SNR`` frames are rejected either way).
    A bearing whose ±3σ reaches past the phase field of view is flagged
    ``MAY_BE_OUTSIDE`` (the edge rule of :mod:`rfsas_hw.df.fovrule`).

    Raises:
        CalibrationError: as :func:`estimate_phase`.
    """
    res, _ = estimate_phase(cal, batch, mono=mono)
    flags = (mono.flags & np.uint8(DfFlag.LOW_SNR)).astype(np.uint8)
    for src, dst in (
        (IfFlag.MISSING_CHAIN, DfFlag.MISSING_CHAIN),
        (IfFlag.OUTSIDE_FOV, DfFlag.OUTSIDE_FOV),
        (IfFlag.NO_TABLE, DfFlag.NO_TABLE),
        (IfFlag.AMBIGUOUS, DfFlag.AMBIGUOUS),
    ):
        flags |= ((res.flags & np.uint8(src)) != 0).astype(np.uint8) * np.uint8(dst)
    assert cal.phase is not None  # estimate_phase raised otherwise
    edge = near_edge(res.angle_deg, res.sigma_deg, cal.phase.fov_deg) & (flags == 0)
    flags |= edge.view(np.uint8) * np.uint8(DfFlag.MAY_BE_OUTSIDE)
    bad = flags != 0
    angle = np.where(bad, np.nan, res.angle_deg).astype(np.float32)
    sigma = np.where(bad, np.nan, res.sigma_deg).astype(np.float32)
    return DfResult(angle, sigma, mono.snr_db, flags)
