"""Calibration files: YAML with a format name and version, validated on load.

Version 1 files may carry two optional per-table keys of the σ model,
``model_sigma_deg`` (the fit's model error) and ``env_floor_deg`` (the
environment floor a check measured), both degrees, both 0 when absent, and
``level_db`` (the stronger chain's reading relative to boresight on the grid,
dB), which the field-of-view rules use (:mod:`rfsas_hw.df.fovrule`). An optional
``array:`` section holds an array's geometry and per-element phase and gain
(:mod:`rfsas_hw.df.arraycal`).

Every problem names the file and the key, e.g.
``cal.yaml: tables[0].psi: 40 values for a grid of 41``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from rfsas_hw.config import from_mapping, read_yaml
from rfsas_hw.df.arraycal import array_from_mapping, array_to_mapping
from rfsas_hw.df.calibration import (
    FORMAT_NAME,
    FORMAT_VERSION,
    Calibration,
    CalibrationTable,
)
from rfsas_hw.df.monopulse import Mode
from rfsas_hw.df.phasecal import phase_from_mapping, phase_to_mapping
from rfsas_hw.df.validate import check_calibration, raise_on_errors
from rfsas_hw.errors import CalibrationError, ConfigError
from rfsas_hw.outpaths import write_text_atomic

log = logging.getLogger(__name__)


@dataclass
class _ReceiverDoc:
    step_db: float = 1.0
    noise_floor_dbm: float = -90.89
    saturation_dbm: float = -10.0


@dataclass
class _TableDoc:
    k_d: float
    fov_deg: tuple[float, float]
    noise_db: float
    grid_deg: list[float]
    psi: list[float]
    channel: int | None = None
    samples: int = 0
    residual_rms_deg: float | None = None
    model_sigma_deg: float = 0.0
    env_floor_deg: float = 0.0
    level_db: list[float] | None = None


@dataclass
class _FileDoc:
    format: str
    version: int
    mode: Mode
    tables: list[_TableDoc]
    created: str = ""
    antenna: dict[str, Any] = field(default_factory=dict)
    receiver: _ReceiverDoc = field(default_factory=_ReceiverDoc)
    phase: Any = None
    array: Any = None


def _check_table(doc: _TableDoc, where: str) -> CalibrationTable:
    grid = np.asarray(doc.grid_deg, dtype=np.float64)
    psi = np.asarray(doc.psi, dtype=np.float64)
    if len(grid) < 2:
        raise CalibrationError(f"{where}.grid_deg: needs at least 2 angles")
    if not np.all(np.isfinite(grid)) or np.any(np.diff(grid) <= 0):
        raise CalibrationError(f"{where}.grid_deg: angles must be finite and strictly increasing")
    if len(psi) != len(grid):
        raise CalibrationError(f"{where}.psi: {len(psi)} values for a grid of {len(grid)}")
    if not np.all(np.isfinite(psi)):
        raise CalibrationError(f"{where}.psi: values must be finite")
    if not (math.isfinite(doc.k_d) and doc.k_d > 0):
        raise CalibrationError(f"{where}.k_d: must be a positive number, got {doc.k_d}")
    lo, hi = doc.fov_deg
    if not (grid[0] - 1e-9 <= lo < hi <= grid[-1] + 1e-9):
        raise CalibrationError(
            f"{where}.fov_deg: [{lo:g}, {hi:g}] is not an interval inside the grid "
            f"[{grid[0]:g}, {grid[-1]:g}]"
        )
    inside = (grid >= lo - 1e-9) & (grid <= hi + 1e-9)
    d = np.diff(psi[inside])
    if not (np.all(d > 0) or np.all(d < 0)):
        raise CalibrationError(f"{where}.psi: not strictly monotonic inside fov_deg")
    if not (math.isfinite(doc.noise_db) and doc.noise_db >= 0):
        raise CalibrationError(f"{where}.noise_db: must be ≥ 0, got {doc.noise_db}")
    for key in ("model_sigma_deg", "env_floor_deg"):
        value = getattr(doc, key)
        if not (math.isfinite(value) and value >= 0):
            raise CalibrationError(f"{where}.{key}: must be a number ≥ 0 degrees, got {value}")
    level = None
    if doc.level_db is not None:
        level = np.asarray(doc.level_db, dtype=np.float64)
        if len(level) != len(grid) or not np.all(np.isfinite(level)):
            raise CalibrationError(
                f"{where}.level_db: {len(level)} values for a grid of {len(grid)}, all finite"
            )
    rms = float("nan") if doc.residual_rms_deg is None else doc.residual_rms_deg
    try:
        return CalibrationTable(
            doc.channel,
            doc.k_d,
            grid,
            psi,
            (lo, hi),
            doc.noise_db,
            doc.samples,
            rms,
            doc.model_sigma_deg,
            doc.env_floor_deg,
            level,
        )
    except CalibrationError as err:
        raise CalibrationError(f"{where}: {err}") from err


def calibration_from_mapping(data: Any, where: str = "calibration") -> Calibration:
    """Validate a parsed calibration document and build the :class:`Calibration`.

    Raises:
        CalibrationError: wrong format or version, unknown or missing key,
            wrong type, or inconsistent tables; the message names the key.
    """
    if not isinstance(data, Mapping):
        raise CalibrationError(f"{where}: expected a mapping at the top level")
    if data.get("format") != FORMAT_NAME:
        raise CalibrationError(
            f"{where}: format: expected {FORMAT_NAME!r}, got {data.get('format')!r}"
        )
    if data.get("version") != FORMAT_VERSION:
        raise CalibrationError(
            f"{where}: version: {data.get('version')!r} is not supported "
            f"(this build reads {FORMAT_VERSION})"
        )
    try:
        doc = from_mapping(_FileDoc, data, where)
    except ConfigError as err:
        raise CalibrationError(str(err)) from err
    tables = tuple(_check_table(t, f"{where}: tables[{i}]") for i, t in enumerate(doc.tables))
    phase = None if doc.phase is None else phase_from_mapping(doc.phase, f"{where}: phase")
    array = None if doc.array is None else array_from_mapping(doc.array, f"{where}: array")
    try:
        return Calibration(
            mode=doc.mode,
            tables=tables,
            step_db=doc.receiver.step_db,
            noise_floor_dbm=doc.receiver.noise_floor_dbm,
            saturation_dbm=doc.receiver.saturation_dbm,
            antenna=doc.antenna,
            created=doc.created,
            phase=phase,
            array=array,
        )
    except CalibrationError as err:
        raise CalibrationError(f"{where}: tables: {err}") from err


def load_calibration(path: str | Path) -> Calibration:
    """Read and validate a calibration YAML file: its format, then its physics and
    procedure (:mod:`rfsas_hw.df.validate`); warnings are logged.

    Raises:
        CalibrationError: unreadable file, invalid YAML, invalid content, or a table
            that is not credible (|ψ| ≥ 1, a ±900° grid, a 2° field of view, K_D far
            from 1); the file and key are named.
    """
    try:
        data = read_yaml(path)
    except ConfigError as err:
        raise CalibrationError(str(err)) from err
    cal = calibration_from_mapping(data, str(path))
    for finding in raise_on_errors(check_calibration(cal, str(path)), "calibration"):
        log.warning("%s", finding)
    return cal


class _FlowList(list[float]):
    """A list YAML writes on one line."""


def _flow_list(dumper: yaml.SafeDumper, data: _FlowList) -> yaml.SequenceNode:
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=True)


class _Dumper(yaml.SafeDumper):
    pass


_Dumper.add_representer(_FlowList, _flow_list)


def calibration_to_mapping(cal: Calibration) -> dict[str, Any]:
    """The YAML document of ``cal`` (plain types only)."""
    tables = []
    for t in cal.tables:
        # the σ-model terms are optional keys, written only when set, so files
        # without them stay byte-identical and readable by older builds
        sigma_terms = {
            key: round(float(value), 4)
            for key, value in (
                ("model_sigma_deg", t.model_sigma_deg),
                ("env_floor_deg", t.env_floor_deg),
            )
            if value > 0
        }
        tables.append(
            {
                "channel": t.channel,
                "k_d": float(f"{t.k_d:.9g}"),
                "fov_deg": _FlowList([float(t.fov_deg[0]), float(t.fov_deg[1])]),
                "noise_db": round(float(t.noise_db), 4),
                "samples": int(t.samples),
                "residual_rms_deg": None
                if math.isnan(t.residual_rms_deg)
                else round(float(t.residual_rms_deg), 4),
                **sigma_terms,
                "grid_deg": _FlowList([round(float(v), 6) for v in t.grid_deg]),
                "psi": _FlowList([float(f"{v:.9g}") for v in t.psi]),
                **(
                    {}
                    if t.level_db is None
                    else {"level_db": _FlowList([round(float(v), 3) for v in t.level_db])}
                ),
            }
        )
    return {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "mode": cal.mode,
        "created": cal.created,
        "antenna": dict(cal.antenna),
        "receiver": {
            "step_db": cal.step_db,
            "noise_floor_dbm": cal.noise_floor_dbm,
            "saturation_dbm": cal.saturation_dbm,
        },
        "tables": tables,
        **({} if cal.phase is None else {"phase": phase_to_mapping(cal.phase)}),
        **({} if cal.array is None else {"array": array_to_mapping(cal.array)}),
    }


def save_calibration(cal: Calibration, path: str | Path) -> None:
    """Write ``cal`` as YAML (round-trips through :func:`load_calibration`), beside the
    target first and renamed over it, so a failed write never leaves half a table.

    Raises:
        ConfigError: the file cannot be written.
    """
    text = yaml.dump(calibration_to_mapping(cal), Dumper=_Dumper, sort_keys=False, width=100)
    write_text_atomic(path, text)
