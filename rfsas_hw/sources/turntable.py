"""Calibration samples from a capture: a turntable angle log joined with an emitter's frames.

The antenna pair sits on a turntable (or the reference emitter is walked
around it) while a capture runs. The turntable writes a log of (time, angle);
every frame of the reference emitter heard on both antennas becomes one
sample ``(angle_deg, rssi1_dbm, rssi2_dbm, channel)`` with the angle the log
gives for the frame's capture time.

Angle log CSV: a header row, a time column (``t_ns``, ``time_s``/``unix_s``/
``time``/``timestamp``: UTC nanoseconds, Unix seconds, or ISO 8601 with a
time zone) and an angle column (``angle_deg`` or ``angle``: degrees clockwise
from boresight). Rows must be in time order.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Literal

import numpy as np
import numpy.typing as npt

from rfsas_hw.angles import wrap_deg_180
from rfsas_hw.config import read_text_input
from rfsas_hw.errors import DataFormatError
from rfsas_hw.records import ObservationBatch, ObsFlag, mac_to_int
from rfsas_hw.rf.synth import TurntableSamples

TIME_COLUMNS = ("t_ns", "time_s", "unix_s", "time", "timestamp")
ANGLE_COLUMNS = ("angle_deg", "angle")
NS_PER_S = 1_000_000_000
MAX_T_NS = 2**63 - 1
"""Latest time an int64 nanosecond stamp can hold (2262)."""


@dataclass(frozen=True)
class AngleLog:
    """Turntable angle against time."""

    t_ns: npt.NDArray[np.int64]
    """UTC nanoseconds, non-decreasing."""
    angle_deg: npt.NDArray[np.float64]
    """Degrees clockwise from boresight."""


@dataclass
class JoinStats:
    """How many of the emitter's frames became samples."""

    emitter_frames: int = 0
    """Frames from the reference emitter."""
    samples: int = 0
    """Frames turned into samples."""
    outside_log: int = 0
    """Frames before the first or after the last log row."""
    in_log_gap: int = 0
    """Frames in a gap between log rows longer than the allowed one."""
    missing_antenna: int = 0
    """Frames without a value on both antennas."""


def _time_ns(text: str, column: str, where: str) -> int:
    value = text.strip()
    try:
        number = float(value)
    except ValueError:
        try:
            stamp = datetime.fromisoformat(value.replace("Z", "+00:00"))
        except ValueError as err:
            raise DataFormatError(f"{where}: {column} {value!r} is not a time") from err
        if stamp.tzinfo is None:
            raise DataFormatError(
                f"{where}: {column} {value!r} has no time zone (use Z or +00:00)"
            ) from None
        return round(stamp.timestamp() * NS_PER_S)
    if not abs(number) < float("inf"):
        raise DataFormatError(f"{where}: {column} {value!r} is not a finite time")
    t = (
        (int(value) if value.lstrip("-").isdigit() else round(number))
        if column == "t_ns"
        else (round(number * NS_PER_S))
    )
    if not 0 <= t < MAX_T_NS:
        hint = " (milliseconds? this column is in seconds)" if column != "t_ns" else ""
        raise DataFormatError(
            f"{where}: {column} {value!r} is not a time between 1970 and 2262{hint}"
        )
    return t


def read_angle_log(path: str | Path) -> AngleLog:
    """Read a turntable angle log CSV.

    Raises:
        DataFormatError: unreadable file, missing column, a bad value (with its
            line), rows out of time order, or no rows.
    """
    p = Path(path)
    text = read_text_input(p, "CSV", error=DataFormatError)
    try:
        return _parse_angle_log(p, text)
    except csv.Error as err:
        raise DataFormatError(f"{p}: not a CSV file: {err}") from err


def _parse_angle_log(p: Path, text: str) -> AngleLog:
    times: list[int] = []
    angles: list[float] = []
    with io.StringIO(text, newline="") as handle:
        reader = csv.reader(handle)
        header = [h.strip().lower() for h in next(reader, [])]
        t_col = next((c for c in TIME_COLUMNS if c in header), None)
        a_col = next((c for c in ANGLE_COLUMNS if c in header), None)
        if t_col is None or a_col is None:
            raise DataFormatError(
                f"{p}: line 1: need a time column ({', '.join(TIME_COLUMNS)}) and an angle "
                f"column ({', '.join(ANGLE_COLUMNS)}); found {header}"
            )
        ti, ai = header.index(t_col), header.index(a_col)
        for line_no, row in enumerate(reader, start=2):
            if not row or not any(cell.strip() for cell in row):
                continue
            where = f"{p}: line {line_no}"
            if len(row) <= max(ti, ai):
                raise DataFormatError(f"{where}: expected {len(header)} columns, got {len(row)}")
            t = _time_ns(row[ti], t_col, where)
            try:
                angle = float(row[ai])
            except ValueError as err:
                raise DataFormatError(f"{where}: {a_col} {row[ai]!r} is not a number") from err
            if not abs(angle) < float("inf"):
                raise DataFormatError(f"{where}: {a_col} {row[ai]!r} is not finite")
            if times and t < times[-1]:
                raise DataFormatError(f"{where}: time goes backwards")
            times.append(t)
            angles.append(angle)
    if not times:
        raise DataFormatError(f"{p}: no rows")
    return AngleLog(np.asarray(times, np.int64), np.asarray(angles, np.float64))


def angles_at(
    log: AngleLog,
    t_ns: npt.NDArray[np.int64],
    max_gap_s: float = 2.0,
    mode: Literal["interp", "hold"] = "interp",
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
    """The log's angle at each time.

    ``interp`` interpolates linearly between rows (across ±180° the short way);
    ``hold`` keeps the last row's angle (step-and-dwell tables).

    Returns (angle in degrees, inside the log's time span, not in a gap longer
    than ``max_gap_s``).
    """
    t = np.asarray(t_ns, np.int64)
    inside = (t >= log.t_ns[0]) & (t <= log.t_ns[-1])
    after = np.clip(np.searchsorted(log.t_ns, t, side="right"), 1, len(log.t_ns) - 1)
    if len(log.t_ns) == 1:
        return np.full(len(t), log.angle_deg[0]), inside, inside
    gap = (log.t_ns[after] - log.t_ns[after - 1]) <= max_gap_s * NS_PER_S
    if mode == "hold":
        idx = np.clip(np.searchsorted(log.t_ns, t, side="right") - 1, 0, len(log.t_ns) - 1)
        return log.angle_deg[idx], inside, gap
    unwrapped = np.rad2deg(np.unwrap(np.deg2rad(log.angle_deg)))
    rel = (log.t_ns - log.t_ns[0]).astype(np.float64)
    angle = np.interp((t - log.t_ns[0]).astype(np.float64), rel, unwrapped)
    return np.asarray(wrap_deg_180(angle), np.float64), inside, gap


def join_turntable(
    obs: ObservationBatch,
    log: AngleLog,
    emitter: int | str,
    *,
    max_gap_s: float = 2.0,
    mode: Literal["interp", "hold"] = "interp",
) -> tuple[TurntableSamples, JoinStats]:
    """Samples from the frames of ``emitter`` (MAC as int or text) at the log's angles."""
    mac = mac_to_int(emitter) if isinstance(emitter, str) else int(emitter)
    stats = JoinStats()
    mine = obs.select(obs.mac == np.uint64(mac))
    stats.emitter_frames = len(mine)
    angle, inside, no_gap = angles_at(log, mine.t_ns, max_gap_s, mode)
    both = ~np.isnan(mine.rssi_dbm[:, :2]).any(axis=1) & ((mine.flags & ObsFlag.BAD_FCS) == 0)
    stats.outside_log = int((~inside).sum())
    stats.in_log_gap = int((inside & ~no_gap).sum())
    stats.missing_antenna = int((inside & no_gap & ~both).sum())
    keep = inside & no_gap & both
    stats.samples = int(keep.sum())
    samples = TurntableSamples(
        angle_deg=angle[keep].astype(np.float64),
        rssi1_dbm=mine.rssi_dbm[keep, 0].astype(np.float64),
        rssi2_dbm=mine.rssi_dbm[keep, 1].astype(np.float64),
        channel=mine.channel[keep].astype(np.int16),
    )
    return samples, stats


def samples_from_capture(
    capture: str,
    angles: str | Path,
    emitter: int | str,
    *,
    max_gap_s: float = 2.0,
    mode: Literal["interp", "hold"] = "interp",
) -> tuple[TurntableSamples, JoinStats]:
    """Read a capture (file path or source spec) and an angle log, and join them.

    Raises:
        SourceError / CaptureFormatError: the capture cannot be read.
        DataFormatError: the angle log is malformed, or no sample results.
    """
    import rfsas_hw.sources

    spec = capture if capture.startswith("pcap:") else f"pcap:{capture}"
    log = read_angle_log(angles)
    with rfsas_hw.sources.open(spec) as src:
        batches = list(src)
    obs = ObservationBatch.concat(batches)
    samples, stats = join_turntable(obs, log, emitter, max_gap_s=max_gap_s, mode=mode)
    if stats.samples == 0:
        raise DataFormatError(
            f"{capture}: no samples: {stats.emitter_frames} frames from {emitter}, "
            f"{stats.outside_log} outside the angle log's time span, {stats.in_log_gap} in gaps, "
            f"{stats.missing_antenna} without both antennas"
        )
    return samples, stats
