"""Is a turntable sweep, or a calibration, physically credible and made by the procedure?

A sweep or table can be well-formed and still wrong: a log full of −128 dBm
"no reading" sentinels, a table whose ψ leaves (−1, 1), a ±900° grid, a 2°
field of view, antennas wired the other way round, ten samples, a sweep that
never crosses boresight. Fitted or loaded without a word, each gives bearings
that look precise and are not. This module finds them, in one place, for
``rfsas calibrate`` (the sweep before the fit, the table after it) and for
:func:`~rfsas_hw.df.calfile.load_calibration` (every table on load).

Each finding is an ``error`` (the result would be wrong: refuse it) or a
``warning`` (unusual, possibly right: say so loudly). Thresholds and why:

- RSSI at or below −128 dBm (the int8 minimum drivers write for "no value", a
  "sentinel") or at or above +20 dBm is not a reading; below −110 dBm no
  receiver decodes a frame, so such readings are warned about.
- ψ = (P₁ − K·P₂)/(P₁ + K·P₂) lies strictly inside (−1, 1) for any two
  positive powers (and any two dBm readings of one sign).
- Angles are compass-like degrees from boresight: a grid or sweep beyond ±180°
  is a unit or wrap error.
- A monopulse pair resolves tens of degrees; a field of view narrower than
  10° means the fit found no usable slope (under 30°: unusual).
- K_D balances the chains at boresight: more than 10 dB apart (linear mode)
  means a dead or mis-wired chain (more than 3 dB: check the cabling).
- With antenna 1 squinted clockwise (the convention), ψ rises with the angle
  in linear mode and falls in dB mode (dBm are negative); the other way round
  means the antennas are swapped against the convention.
- A fit needs samples on both sides of boresight (K_D is taken at 0°), at
  least 100 of them over at least 20 distinct angles spanning 30° or more.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from rfsas_hw.df.calibration import Calibration, CalibrationTable
from rfsas_hw.errors import CalibrationError
from rfsas_hw.rf.synth import TurntableSamples

RSSI_RANGE_DBM = (-128.0, 20.0)
"""Possible RSSI readings, dBm, exclusive: −128 (the int8 minimum) is what drivers write
for "no reading", and nothing received is above +20 dBm."""
RSSI_SENSITIVITY_DBM = -110.0
"""Below this no receiver decodes a frame: such readings are suspicious, not impossible
(a simulated chain in a beam null reports them)."""
NOISE_FLOOR_RANGE_DBM = (-130.0, -40.0)
"""Plausible noise floors, dBm."""
MAX_ABS_ANGLE_DEG = 180.0
MIN_FOV_DEG = 10.0
NARROW_FOV_DEG = 30.0
LOPSIDED_DEG = 20.0
"""A field of view whose centre is further than this off boresight is lopsided."""
MAX_KD_DB = 10.0
WARN_KD_DB = 3.0
MIN_SAMPLES = 100
MIN_ANGLES = 20
MIN_SPAN_DEG = 30.0

Level = Literal["error", "warning"]


@dataclass(frozen=True, slots=True)
class Finding:
    """One problem with a sweep or a table."""

    level: Level
    """``error``: refuse the input; ``warning``: accept it, and say so."""
    where: str
    """What it is about: a file and key, e.g. ``cal.yaml: tables[0].k_d``."""
    message: str
    """What is wrong and what to do, one line."""

    def __str__(self) -> str:
        return f"{self.where}: {self.message}"


def _kd_db(table: CalibrationTable, mode: str) -> float:
    """K_D as a chain imbalance in dB (an estimate in dB mode, at −60 dBm)."""
    k = table.k_d
    if mode == "linear":
        return 10.0 * math.log10(k)
    # db mode: ψ = 0 where r1 = K·r2; at r2 = −60 dBm that is (K − 1)·60 dB apart
    return (k - 1.0) * 60.0


def check_table(table: CalibrationTable, mode: str, where: str) -> list[Finding]:
    """Findings for one calibration table fitted in ``mode``."""
    out: list[Finding] = []
    grid, psi = table.grid_deg, table.psi
    if np.any(np.abs(grid) > MAX_ABS_ANGLE_DEG):
        out.append(
            Finding(
                "error",
                f"{where}.grid_deg",
                f"angles reach {float(np.max(np.abs(grid))):g}°; a grid lies within "
                f"±{MAX_ABS_ANGLE_DEG:g}° of boresight (a unit or wrap error?)",
            )
        )
    if np.any(np.abs(psi) >= 1.0):
        out.append(
            Finding(
                "error",
                f"{where}.psi",
                f"|ψ| reaches {float(np.max(np.abs(psi))):g}; a monopulse ratio lies strictly "
                "inside (−1, 1)",
            )
        )
    lo, hi = table.fov_deg
    width = hi - lo
    if width < MIN_FOV_DEG:
        out.append(
            Finding(
                "error",
                f"{where}.fov_deg",
                f"field of view {width:.1f}° wide; under {MIN_FOV_DEG:g}° the fit found no "
                "usable slope (bad sweep?)",
            )
        )
    elif width < NARROW_FOV_DEG:
        out.append(
            Finding("warning", f"{where}.fov_deg", f"narrow field of view: {width:.1f}° wide")
        )
    centre = (lo + hi) / 2
    if abs(centre) > LOPSIDED_DEG:
        out.append(
            Finding(
                "warning",
                f"{where}.fov_deg",
                f"lopsided field of view [{lo:+.1f}°, {hi:+.1f}°]: its centre is {centre:+.1f}° "
                "off boresight (a turntable zero offset?)",
            )
        )
    kd_db = _kd_db(table, mode)
    if abs(kd_db) > MAX_KD_DB:
        out.append(
            Finding(
                "error",
                f"{where}.k_d",
                f"K_D {table.k_d:.4g} puts the chains {kd_db:+.1f} dB apart at boresight: a dead "
                "chain, sentinel readings or a mis-wired antenna",
            )
        )
    elif abs(kd_db) > WARN_KD_DB:
        out.append(
            Finding(
                "warning",
                f"{where}.k_d",
                f"K_D {table.k_d:.4g}: chains {kd_db:+.1f} dB apart at boresight; check cables",
            )
        )
    inside = (grid >= lo) & (grid <= hi)
    if np.count_nonzero(inside) >= 2:
        slope = float(np.mean(np.diff(psi[inside])))
        rising_expected = mode == "linear"
        if slope != 0 and (slope > 0) != rising_expected:
            out.append(
                Finding(
                    "warning",
                    f"{where}.psi",
                    f"ψ {'falls' if slope < 0 else 'rises'} with the angle: antennas 1 and 2 "
                    "are swapped against the convention (antenna 1 squinted clockwise); "
                    "bearings are mirrored unless the sensor is wired the same way",
                )
            )
    return out


def check_calibration(cal: Calibration, where: str = "calibration") -> list[Finding]:
    """Findings for a whole calibration: receiver facts and every table."""
    out: list[Finding] = []
    lo, hi = NOISE_FLOOR_RANGE_DBM
    if not (math.isfinite(cal.noise_floor_dbm) and lo <= cal.noise_floor_dbm <= hi):
        out.append(
            Finding(
                "error",
                f"{where}: receiver.noise_floor_dbm",
                f"{cal.noise_floor_dbm} dBm is not a noise floor (expected {lo:g}…{hi:g} dBm)",
            )
        )
    if not math.isfinite(cal.saturation_dbm) or cal.saturation_dbm <= cal.noise_floor_dbm:
        out.append(
            Finding(
                "error",
                f"{where}: receiver.saturation_dbm",
                f"{cal.saturation_dbm} dBm must be finite and above the noise floor",
            )
        )
    if not (math.isfinite(cal.step_db) and 0.0 <= cal.step_db <= 10.0):
        out.append(
            Finding("error", f"{where}: receiver.step_db", f"{cal.step_db} dB is not 0…10 dB")
        )
    for i, table in enumerate(cal.tables):
        out.extend(check_table(table, cal.mode, f"{where}: tables[{i}]"))
    return out


def check_samples(
    samples: TurntableSamples, where: str = "samples", noise_floor_dbm: float | None = None
) -> list[Finding]:
    """Findings for a turntable sweep before it is fitted."""
    out: list[Finding] = []
    n = len(samples.angle_deg)
    r1, r2, angle = samples.rssi1_dbm, samples.rssi2_dbm, samples.angle_deg
    lo, hi = RSSI_RANGE_DBM
    for name, values in (("rssi1_dbm", r1), ("rssi2_dbm", r2)):
        bad = ~np.isfinite(values) | (values <= lo) | (values >= hi)
        if bad.any():
            shown = ", ".join(f"{v:g}" for v in np.unique(values[bad])[:3])
            out.append(
                Finding(
                    "error",
                    f"{where}: {name}",
                    f"{int(bad.sum())} of {n} readings are {shown} dBm, outside {lo:g}…{hi:g}: "
                    "driver sentinels for 'no reading'; drop those rows",
                )
            )
        weak = ~bad & (values < RSSI_SENSITIVITY_DBM)
        if weak.any():
            out.append(
                Finding(
                    "warning",
                    f"{where}: {name}",
                    f"{int(weak.sum())} of {n} readings below {RSSI_SENSITIVITY_DBM:g} dBm, "
                    "under any receiver's sensitivity: sentinels or a dead chain?",
                )
            )
    if noise_floor_dbm is not None and not (
        math.isfinite(noise_floor_dbm)
        and NOISE_FLOOR_RANGE_DBM[0] <= noise_floor_dbm <= NOISE_FLOOR_RANGE_DBM[1]
    ):
        out.append(
            Finding(
                "error",
                "--noise-floor",
                f"{noise_floor_dbm} dBm is not a noise floor (expected "
                f"{NOISE_FLOOR_RANGE_DBM[0]:g}…{NOISE_FLOOR_RANGE_DBM[1]:g} dBm)",
            )
        )
    if np.any(np.abs(angle) > MAX_ABS_ANGLE_DEG):
        out.append(
            Finding(
                "error",
                f"{where}: angle_deg",
                f"angles reach {float(np.max(np.abs(angle))):g}°; give degrees from boresight "
                f"within ±{MAX_ABS_ANGLE_DEG:g}°",
            )
        )
    if n < MIN_SAMPLES:
        out.append(Finding("error", where, f"{n} samples; a fit needs at least {MIN_SAMPLES}"))
    distinct = len(np.unique(np.round(angle, 1)))
    if distinct < MIN_ANGLES:
        out.append(
            Finding(
                "error",
                f"{where}: angle_deg",
                f"{distinct} distinct angles; a sweep needs at least {MIN_ANGLES}",
            )
        )
    if n:
        a_min, a_max = float(np.min(angle)), float(np.max(angle))
        if not a_min <= 0.0 <= a_max:
            out.append(
                Finding(
                    "error",
                    f"{where}: angle_deg",
                    f"the sweep covers {a_min:+g}°…{a_max:+g}° and misses boresight (0°), "
                    "where K_D is taken",
                )
            )
        elif a_max - a_min < MIN_SPAN_DEG:
            out.append(
                Finding(
                    "error",
                    f"{where}: angle_deg",
                    f"the sweep spans {a_max - a_min:g}°; at least {MIN_SPAN_DEG:g}° is needed",
                )
            )
        elif abs((a_min + a_max) / 2) > 2 * LOPSIDED_DEG:
            out.append(
                Finding(
                    "warning",
                    f"{where}: angle_deg",
                    f"lopsided sweep {a_min:+g}°…{a_max:+g}°: one side of boresight is barely "
                    "measured",
                )
            )
    return out


def sentinel_rows(samples: TurntableSamples) -> np.ndarray:
    """Rows whose either reading is not a reading (a sentinel, NaN, or out of range)."""
    lo, hi = RSSI_RANGE_DBM
    bad = np.zeros(len(samples.angle_deg), dtype=bool)
    for values in (samples.rssi1_dbm, samples.rssi2_dbm):
        bad |= ~np.isfinite(values) | (values <= lo) | (values >= hi)
    return bad


def drop_sentinels(samples: TurntableSamples) -> tuple[TurntableSamples, int]:
    """``samples`` without its sentinel rows, and how many were dropped (for a check, where
    a few bad rows should cost only themselves; a fit refuses them instead)."""
    bad = sentinel_rows(samples)
    if not bad.any():
        return samples, 0
    keep = ~bad
    kept = TurntableSamples(
        samples.angle_deg[keep], samples.rssi1_dbm[keep], samples.rssi2_dbm[keep],
        samples.channel[keep],
    )  # fmt: skip
    return kept, int(bad.sum())


def errors(findings: Iterable[Finding]) -> list[Finding]:
    """The ``error`` findings."""
    return [f for f in findings if f.level == "error"]


def warnings(findings: Iterable[Finding]) -> list[Finding]:
    """The ``warning`` findings."""
    return [f for f in findings if f.level == "warning"]


def raise_on_errors(findings: Iterable[Finding], what: str) -> list[Finding]:
    """Raise for the first error (naming how many there are); return the warnings.

    Raises:
        CalibrationError: at least one ``error`` finding.
    """
    found = list(findings)
    bad = errors(found)
    if bad:
        more = f" (and {len(bad) - 1} more problems)" if len(bad) > 1 else ""
        raise CalibrationError(f"{bad[0]}{more}; {what} refused")
    return warnings(found)
