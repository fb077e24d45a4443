"""``rfsas calibrate CAL.yaml --array SPEC``: an array's per-element phase and gain beside the
amplitude tables.

    rfsas calibrate cal.yaml --array 'bleiq:turntable.btsnoop?elements=8' \\
        --geometry uca:8,0.0735 --angles log.csv -o cal-array.yaml
    rfsas calibrate cal.yaml --array 'bleiq+zephyr:console.txt?elements=4&channel=17' \\
        --geometry ula:4,0.0613 --known-position 3,4 --pose 0,0,0 -o cal-array.yaml
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import click
import numpy as np
from rich.console import Console
from rich.table import Table

from rfsas_hw.cli.options import comma_numbers
from rfsas_hw.df import load_calibration, save_calibration
from rfsas_hw.df.array import ArrayGeometry, load_geometry
from rfsas_hw.df.arraycsi import fit_array_calibration, known_angle_errors_deg
from rfsas_hw.errors import ConfigError

F = TypeVar("F", bound=Callable[..., Any])
ARRAY_KEYS = ("array_capture", "geometry", "array_fov")
"""The options this module adds, as the command receives them."""


def array_options(func: F) -> F:
    """Options of the array calibration (added to ``rfsas calibrate``)."""
    options = [
        click.option(
            "--array",
            "array_capture",
            metavar="SPEC",
            help="Fit an array's element phases and gains from this recording (bleiq:…, "
            "bleiq+zephyr:…, csi:…) of a transmitter at known angles; INPUTS is the "
            "amplitude CAL.yaml to extend; needs --geometry and --angles or --known-position.",
        ),
        click.option(
            "--geometry",
            metavar="SHAPE",
            help="--array: ula:N,SPACING_M, uca:N,RADIUS_M, ura:NX,NY,DX_M,DY_M, or a CSV "
            "of x_m,y_m rows (element k on row k).",
        ),
        click.option(
            "--array-fov",
            "array_fov",
            metavar="LO,HI",
            help="--array: field of view to store, degrees from boresight (default: all).",
        ),
    ]
    for option in reversed(options):
        func = option(func)
    return func


def parse_geometry(text: str) -> ArrayGeometry:
    """``ula:N,SPACING_M``, ``uca:N,RADIUS_M``, ``ura:NX,NY,DX_M,DY_M`` or a CSV path.

    Raises:
        ConfigError: a shape with the wrong numbers, or an impossible array.
        CalibrationError: an unreadable or malformed CSV.
    """
    shape, sep, rest = text.partition(":")
    counts = {"ula": 2, "uca": 2, "ura": 4}
    if not sep or shape not in counts:
        return load_geometry(text)
    values = comma_numbers(rest, counts[shape], f"--geometry {shape}")
    sizes = values[: 2 if shape == "ura" else 1]
    if not all(v.is_integer() and v >= 1 for v in sizes):
        raise ConfigError(f"--geometry {text!r}: element counts must be whole numbers ≥ 1")
    try:
        if shape == "ula":
            return ArrayGeometry.ula(int(values[0]), values[1])
        if shape == "uca":
            return ArrayGeometry.uca(int(values[0]), values[1])
        return ArrayGeometry.ura(int(values[0]), int(values[1]), values[2], values[3])
    except ValueError as err:
        raise ConfigError(f"--geometry {text!r}: {err}") from err


def _rms(err: np.ndarray) -> str:
    ok = err[np.isfinite(err)]
    return f"{math.sqrt(float(np.mean(ok**2))):.2f}° ({len(ok)} frames)" if len(ok) else "—"


def run_array(
    console: Console,
    inputs: tuple[Path, ...],
    output: Path | None,
    angles_path: Path | None,
    emitter: str | None,
    known_position: str | None,
    pose: str,
    *,
    array_capture: str,
    geometry: str | None,
    array_fov: str | None,
) -> None:
    """Fit the element calibration and write the amplitude calibration with it.

    Raises:
        click.UsageError: missing or conflicting options.
        ConfigError, CalibrationError, SourceError, DataFormatError: bad inputs.
    """
    from rfsas_hw.cli.calibrate_reference import reference_frames

    if len(inputs) != 1 or output is None:
        raise click.UsageError("--array takes the amplitude CAL.yaml as INPUT and -o OUT.yaml")
    if geometry is None:
        raise click.UsageError("--array needs --geometry (ula:…, uca:…, ura:… or a CSV)")
    array = parse_geometry(geometry)
    fov = None
    if array_fov is not None:
        lo, hi = comma_numbers(array_fov, 2, "--array-fov")
        if not -180.0 <= lo < hi <= 180.0:
            raise ConfigError(f"--array-fov {array_fov!r}: LO < HI within ±180°")
        fov = (lo, hi)
    amplitude = load_calibration(inputs[0])
    obs, true_deg = reference_frames(
        console,
        array_capture,
        flag="--array",
        emitter=emitter,
        angles_path=angles_path,
        known_position=known_position,
        pose=pose,
    )
    cal = fit_array_calibration(array, obs, true_deg, fov)
    save_calibration(dataclasses.replace(amplitude, array=cal), output)
    table = Table(title=f"Array calibration ({array.n} elements, {cal.freq_mhz:g} MHz) in {output}")
    for col in ("element", "x, y (mm)", "phase", "gain"):
        table.add_column(col, justify="right")
    for k, (pos, ph, g) in enumerate(
        zip(
            array.positions_m, np.degrees(cal.elements.phase_rad), cal.elements.gain_db, strict=True
        )
    ):
        table.add_row(
            str(k), f"{pos[0] * 1e3:+.1f}, {pos[1] * 1e3:+.1f}", f"{ph:+.2f}°", f"{g:+.2f} dB"
        )
    console.print(table)
    before = known_angle_errors_deg(cal, obs, true_deg, calibrated=False)
    after = known_angle_errors_deg(cal, obs, true_deg)
    console.print(
        f"phase residual {math.degrees(cal.elements.residual_rad):.2f}° per element; "
        f"bearing RMS on these frames: {_rms(before)} with ideal elements, {_rms(after)} calibrated"
    )
