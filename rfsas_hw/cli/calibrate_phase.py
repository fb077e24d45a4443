"""``rfsas calibrate --phase CAPTURE``: interferometer phase offsets beside the amplitude tables.

    rfsas calibrate cal.yaml --phase csi:turntable.csi?freq=2437 --angles log.csv \\
        --emitter 02:00:00:00:00:01 --baseline 0.0615 -o cal-phase.yaml
    rfsas calibrate cal.yaml --phase csi:fixed.dat?freq=5200 --known-position 12,30 \\
        --pose 0,0,90 --baseline 0.029 -o cal-phase.yaml
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import click
from rich.console import Console
from rich.table import Table

from rfsas_hw.cli.options import comma_numbers
from rfsas_hw.df import load_calibration, save_calibration
from rfsas_hw.df.phasecal import PhaseCalibration, fit_phase_pair
from rfsas_hw.errors import ConfigError

F = TypeVar("F", bound=Callable[..., Any])


def phase_options(func: F) -> F:
    """Options of the phase calibration (added to ``rfsas calibrate``)."""
    options = [
        click.option(
            "--phase",
            "phase_capture",
            help="Fit the interferometer phase from this CSI capture (csi:FILE[?freq=…]); "
            "INPUTS is the amplitude CAL.yaml to extend; needs --baseline and --angles or "
            "--known-position.",
        ),
        click.option("--baseline", "baseline_m", type=float, help="--phase: antenna spacing, m."),
        click.option(
            "--pair", "pair", default="0,1", show_default=True, help="--phase: antennas A,B."
        ),
        click.option(
            "--known-position",
            "known_position",
            help="--phase/--array: the reference transmitter stands at X_M,Y_M (local frame).",
        ),
        click.option(
            "--pose",
            "phase_pose",
            default="0,0,0",
            show_default=True,
            help="--phase/--array with --known-position: sensor X_M,Y_M,HEADING_DEG (compass).",
        ),
        click.option(
            "--phase-fov",
            "phase_fov",
            default="-60,60",
            show_default=True,
            help="--phase: interferometer field of view LO,HI, degrees from boresight.",
        ),
    ]
    for option in reversed(options):
        func = option(func)
    return func


def run_phase(
    console: Console,
    inputs: tuple[Path, ...],
    output: Path | None,
    angles_path: Path | None,
    emitter: str | None,
    single_table: bool,
    *,
    phase_capture: str,
    baseline_m: float | None,
    pair: str,
    known_position: str | None,
    phase_pose: str,
    phase_fov: str,
) -> None:
    """Fit the phase offsets and write the amplitude calibration with them.

    Raises:
        click.UsageError: missing or conflicting options.
        ConfigError, CalibrationError, SourceError, DataFormatError: bad inputs.
    """
    from rfsas_hw.cli.calibrate_reference import reference_frames

    if len(inputs) != 1 or output is None:
        raise click.UsageError("--phase takes the amplitude CAL.yaml as INPUT and -o OUT.yaml")
    if baseline_m is None or not 0 < baseline_m < 100:
        raise click.UsageError("--phase needs --baseline METRES (> 0)")
    a_f, b_f = comma_numbers(pair, 2, "--pair")
    if not (a_f.is_integer() and b_f.is_integer() and 0 <= a_f < 8 and 0 <= b_f < 8 and a_f != b_f):
        raise ConfigError(f"--pair {pair!r}: two different antenna numbers 0–7, e.g. 0,1")
    a, b = int(a_f), int(b_f)
    lo, hi = comma_numbers(phase_fov, 2, "--phase-fov")
    amplitude = load_calibration(inputs[0])
    obs, true_deg = reference_frames(
        console,
        phase_capture,
        flag="--phase",
        emitter=emitter,
        angles_path=angles_path,
        known_position=known_position,
        pose=phase_pose,
    )
    assert obs.csi is not None
    fitted = fit_phase_pair(
        obs.csi,
        true_deg,
        obs.freq_mhz,
        obs.channel,
        baseline_m,
        a=a,
        b=b,
        per_channel=not single_table,
    )
    phase = PhaseCalibration((fitted,), (lo, hi))
    save_calibration(dataclasses.replace(amplitude, phase=phase), output)
    table = Table(title=f"Phase calibration (antennas {a}→{b}, D = {baseline_m:g} m) in {output}")
    for col in ("channel", "frames", "offset", "chain delay", "residual"):
        table.add_column(col, justify="right")
    for o in fitted.offsets:
        table.add_row(
            "all" if o.channel is None else str(o.channel),
            str(o.samples),
            f"{o.offset_deg:+.2f}°",
            f"{o.delay_ns:+.3f} ns",
            f"{o.residual_deg:.2f}°",
        )
    console.print(table)
