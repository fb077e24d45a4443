"""Phase calibration frames from a CSI capture: a reference transmitter at known angles.

Two ways to know the angle of each frame:

* a turntable angle log (the CSV of :mod:`rfsas_hw.sources.turntable`), its
  times in the capture's clock (UTC for PicoScenes and nexmon, the tool's own
  clock for Intel 5300, Atheros and FeitCSI — ``t_ns`` counted as that tool
  counts);
* a transmitter at a surveyed position: the angle from the sensor's pose.

:func:`fit_phase_pair` in :mod:`rfsas_hw.df.phasecal` then turns the frames
into the pair's offsets, one per channel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from rfsas_hw.angles import math_rad_to_compass, wrap_deg_180
from rfsas_hw.errors import CalibrationError
from rfsas_hw.records import ObservationBatch, Pose, mac_to_int
from rfsas_hw.sources.base import Source
from rfsas_hw.sources.csi import CsiSource
from rfsas_hw.sources.registry import open_source, schemes
from rfsas_hw.sources.turntable import angles_at, read_angle_log


@dataclass
class PhaseJoin:
    """How many frames of the capture became calibration frames."""

    frames: int = 0
    """Frames in the capture."""
    emitter_frames: int = 0
    """Frames from the reference transmitter."""
    used: int = 0
    """Frames with a known angle (and CSI)."""
    outside_log: int = 0
    """Frames outside the angle log's time span or in a gap of it."""


def known_angle_deg(pose: Pose, x_m: float, y_m: float) -> float:
    """Angle of a transmitter at (x, y) from the sensor's boresight, degrees clockwise.

    Raises:
        CalibrationError: the transmitter stands on the sensor.
    """
    dx, dy = x_m - pose.x_m, y_m - pose.y_m
    if math.hypot(dx, dy) < 1e-6:
        raise CalibrationError("the known transmitter position is the sensor's own position")
    azimuth = float(math_rad_to_compass(math.atan2(dy, dx)))
    return float(wrap_deg_180(azimuth - pose.heading_deg))


def phase_frames(
    capture: str | Path,
    *,
    emitter: str | None = None,
    angles_path: str | Path | None = None,
    known_deg: float | None = None,
    max_gap_s: float = 2.0,
    freq_mhz: int = 0,
) -> tuple[ObservationBatch, npt.NDArray[np.float64], PhaseJoin]:
    """The reference transmitter's frames with CSI and the true angle of each.

    Args:
        capture: CSI file (``csi:`` query options allowed after ``?``), or the spec
            of another source whose observations carry CSI (``bleiq:…``,
            ``bleiq+zephyr:…``: an array's IQ snapshots).
        emitter: MAC of the reference transmitter; None takes every frame (for
            formats that record no address, e.g. Intel 5300 and Atheros).
        angles_path: turntable angle log; or
        known_deg: one angle for every frame (a transmitter at a known position).
        max_gap_s: longest gap between log rows to interpolate over.
        freq_mhz: channel frequency for formats that do not record it.

    Raises:
        CalibrationError: neither or both angle sources, no frame of the emitter
            (the format may carry no address), or no frame with a known angle.
        SourceError, CaptureFormatError: the capture cannot be read.
        DataFormatError: the angle log is malformed.
    """
    if (angles_path is None) == (known_deg is None):
        raise CalibrationError("give a turntable angle log or a known transmitter angle (one)")
    scheme, sep, rest = str(capture).partition(":")
    src: Source[ObservationBatch]
    if sep and scheme != "csi" and scheme in schemes():
        path = rest.partition("?")[0]
        src = open_source(str(capture))
    else:
        arg = str(capture).removeprefix("csi:")
        path = arg.partition("?")[0]
        src = CsiSource.from_spec(arg, **({"freq_mhz": freq_mhz} if freq_mhz else {}))
    try:
        batches = list(src)
    finally:
        src.close()
    obs = ObservationBatch.concat(batches) if batches else ObservationBatch.empty()
    join = PhaseJoin(frames=len(obs))
    if emitter is not None:
        mac = mac_to_int(emitter)
        keep = obs.mac == np.uint64(mac)
        if not keep.any():
            has_macs = bool(np.any(obs.mac != 0))
            raise CalibrationError(
                f"{path}: no frame from {emitter}"
                + ("" if has_macs else " (this format records no transmitter address: omit it)")
            )
        obs = obs.select(keep)
    join.emitter_frames = len(obs)
    if known_deg is not None:
        true = np.full(len(obs), float(known_deg))
        ok = np.ones(len(obs), bool)
    else:
        assert angles_path is not None
        log = read_angle_log(angles_path)
        true, inside, no_gap = angles_at(log, obs.t_ns, max_gap_s)
        ok = inside & no_gap
        join.outside_log = int((~ok).sum())
    obs, true = obs.select(ok), np.asarray(true, np.float64)[ok]
    join.used = len(obs)
    if join.used == 0:
        raise CalibrationError(f"{path}: no frame of the reference transmitter has a known angle")
    return obs, true, join
