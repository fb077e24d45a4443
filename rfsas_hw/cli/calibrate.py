"""``rfsas calibrate``: fit a calibration table from turntable samples, or check one."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import click
from rich.console import Console
from rich.table import Table

from rfsas_hw.cli.calibrate_array import ARRAY_KEYS, array_options, run_array
from rfsas_hw.cli.calibrate_phase import phase_options, run_phase
from rfsas_hw.cli.exitcodes import WorkFailed
from rfsas_hw.cli.options import json_option, out_option
from rfsas_hw.cli.outopts import OutputPath
from rfsas_hw.df import MODES, fit_calibration, load_calibration, read_samples_csv, save_calibration
from rfsas_hw.df.calibration import Calibration
from rfsas_hw.df.check import (
    CONFIDENT_WRONG_MAX,
    CONFIDENT_WRONG_SIGMAS,
    CONSISTENT_RATIO,
    MIN_FLOOR_SAMPLES,
    CheckReport,
    check_calibration,
    with_environment_floor,
)
from rfsas_hw.df.plot import plot_calibration
from rfsas_hw.df.validate import Finding, check_samples, drop_sentinels, raise_on_errors
from rfsas_hw.df.validate import check_calibration as validate_calibration
from rfsas_hw.outpaths import check_output


def _fmt(value: float, unit: str = "", digits: int = 2) -> str:
    return "—" if math.isnan(value) else f"{value:.{digits}f}{unit}"


def _summary(cal: Calibration, out: Path) -> Table:
    table = Table(title=f"Calibration written to {out} ({cal.mode} mode)")
    for col in ("channel", "samples", "K_D", "field of view", "RSSI noise", "residual RMS"):
        table.add_column(col, justify="right")
    for t in cal.tables:
        table.add_row(
            "all" if t.channel is None else str(t.channel),
            str(t.samples),
            f"{t.k_d:.4f}",
            f"{t.fov_deg[0]:+.1f}° … {t.fov_deg[1]:+.1f}°",
            _fmt(t.noise_db, " dB"),
            _fmt(t.residual_rms_deg, "°"),
        )
    return table


def _check_table(report: CheckReport, cal_path: Path, samples_path: Path) -> Table:
    table = Table(title=f"Check of {cal_path} on {samples_path}")
    table.add_column("quantity")
    table.add_column("value", justify="right")
    table.add_row("samples", str(report.samples))
    table.add_row("inside field of view", str(report.inside_fov))
    table.add_row("bearings (all scored)", str(report.valid))
    table.add_row("  of them from outside the FoV", str(report.outside_bearings))
    for reason, count in sorted(report.rejected.items()):
        table.add_row(f"  rejected: {reason}", str(count))
    table.add_row("RMS bearing error", _fmt(report.rms_error_deg, "°"))
    table.add_row("RMS predicted σ", _fmt(report.rms_sigma_deg, "°"))
    table.add_row("error / σ", _fmt(report.ratio, "", 3))
    table.add_row("max |error|", _fmt(report.max_abs_error_deg, "°"))
    share = report.confident_wrong_share
    table.add_row(
        f"confident-wrong (error > {CONFIDENT_WRONG_SIGMAS:g}σ)",
        "—" if math.isnan(share) else f"{report.confident_wrong} ({share:.1%})",
    )
    table.add_row("RMS error of a constant guess", _fmt(report.constant_rms_deg, "°"))
    limits = f"σ within {CONSISTENT_RATIO}×, ≤ {CONFIDENT_WRONG_MAX:.0%} confident-wrong"
    verdict = "consistent" if report.consistent else "NOT consistent"
    table.add_row("verdict", f"{verdict} ({limits})")
    _sigma_rows(table, report)
    return table


def _sigma_rows(table: Table, report: CheckReport) -> None:
    """The σ model's terms, the dominant one, and the environment floor the check measured."""
    terms = report.terms
    table.add_row("σ term: reading noise (RMS)", _fmt(terms.noise_deg, "°"))
    table.add_row("σ term: calibration model error", _fmt(terms.model_deg, "°"))
    table.add_row("σ term: stored environment floor", _fmt(terms.environment_deg, "°"))
    if report.valid:
        table.add_row("dominant σ term", terms.dominant)
    if report.band_ratios:
        bands = " ".join(_fmt(r, "", 2) for r in report.band_ratios)
        table.add_row("error / σ by σ band (small σ first)", bands)
    for channel, floor in sorted(report.measured_floor_deg.items(), key=lambda kv: kv[0] or 0):
        name = "all channels" if channel is None else f"channel {channel}"
        table.add_row(f"measured environment floor, {name}", _fmt(floor, "°"))
    if report.measured_floor_deg:
        table.add_row("error / σ with measured floor", _fmt(report.ratio_with_floor, "", 3))


def _warn(findings: list[Finding]) -> None:
    """Warnings of the credibility checks, loudly, on stderr."""
    console = Console(stderr=True)
    for finding in findings:
        console.print(f"[bold yellow]warning:[/bold yellow] {finding}", highlight=False)


def _num(value: float) -> float | None:
    return None if not math.isfinite(value) else round(float(value), 6)


def check_record(report: CheckReport, cal_path: Path, samples_path: Path) -> dict[str, object]:
    """The ``--check --json`` report: one JSON object (``null`` for what is undefined)."""
    return {
        "calibration": str(cal_path),
        "samples_file": str(samples_path),
        "samples": report.samples,
        "inside_fov": report.inside_fov,
        "valid": report.valid,
        "rejected": dict(report.rejected),
        "rms_error_deg": _num(report.rms_error_deg),
        "rms_sigma_deg": _num(report.rms_sigma_deg),
        "error_over_sigma": _num(report.ratio),
        "max_abs_error_deg": _num(report.max_abs_error_deg),
        "limit": CONSISTENT_RATIO,
        "outside_fov_bearings": report.outside_bearings,
        "confident_wrong": report.confident_wrong,
        "confident_wrong_share": _num(report.confident_wrong_share),
        "confident_wrong_limit": CONFIDENT_WRONG_MAX,
        "constant_guess_rms_deg": _num(report.constant_rms_deg),
        "nothing_to_check": report.nothing_to_check,
        "few_samples": report.few_samples,
        "consistent": bool(report.consistent),
        "problems": report.problems(),
        "sigma_terms_deg": {
            "noise": _num(report.terms.noise_deg),
            "model": _num(report.terms.model_deg),
            "environment": _num(report.terms.environment_deg),
        },
        "dominant_term": report.terms.dominant if report.valid else None,
        "error_over_sigma_by_band": [_num(r) for r in report.band_ratios],
        "measured_floor_deg": {
            "all" if ch is None else str(ch): _num(f) for ch, f in report.measured_floor_deg.items()
        },
        "error_over_sigma_with_floor": _num(report.ratio_with_floor),
    }


@click.command()
@click.argument("inputs", nargs=-1, type=click.Path(path_type=Path))
@out_option(
    "Calibration YAML to write (with --check: CAL.yaml with the measured environment floor).",
    dest="output",
)
@click.option(
    "--plot",
    "plot_path",
    type=OutputPath(),
    help="Draw ψ_D and the samples to this PNG.",
)
@click.option("--check", "check", is_flag=True, help="Check: INPUTS are CAL.yaml SAMPLES.csv.")
@click.option(
    "--mode",
    type=click.Choice(MODES),
    default="linear",
    show_default=True,
    help="Ratio on linear power or on dBm values (the published form).",
)
@click.option(
    "--grid-step",
    type=click.FloatRange(0.01, 10.0),
    default=0.5,
    show_default=True,
    help="Angle grid step of ψ_D, degrees.",
)
@click.option(
    "--single-table",
    is_flag=True,
    help="One table for every channel even if channels are recorded.",
)
@click.option(
    "--step-db",
    type=click.FloatRange(0.0, 10.0),
    default=1.0,
    show_default=True,
    help="RSSI reporting step of the receiver, dB.",
)
@click.option(
    "--noise-floor",
    type=float,
    default=-90.89,
    show_default=True,
    help="Power SNR is measured against, dBm.",
)
@click.option(
    "--antenna", default="", help="Free description of the antenna pair/board, stored in the file."
)
@click.option(
    "--capture",
    help="Fit from a turntable capture (pcap/pcapng) instead of a samples CSV; needs --angles.",
)
@click.option(
    "--angles",
    "angles_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Turntable angle log CSV (time, angle_deg) recorded with --capture.",
)
@click.option("--emitter", help="MAC address of the reference emitter in --capture.")
@click.option("--force", is_flag=True, help="Replace an existing -o/--plot file (never an input).")
@json_option("--check: print the report as one JSON object.")
@phase_options
@array_options
def calibrate(
    inputs: tuple[Path, ...],
    output: Path | None,
    plot_path: Path | None,
    check: bool,
    mode: str,
    grid_step: float,
    single_table: bool,
    step_db: float,
    noise_floor: float,
    antenna: str,
    capture: str | None,
    angles_path: Path | None,
    emitter: str | None,
    force: bool,
    as_json: bool,
    **phase: Any,
) -> None:
    """Fit a monopulse calibration from a turntable CSV (angle_deg,rssi1_dbm,rssi2_dbm[,channel]).

    \b
    rfsas calibrate samples.csv -o cal.yaml --plot cal.png
    rfsas calibrate --check cal.yaml heldback.csv [-o cal-with-floor.yaml]
    rfsas calibrate cal.yaml --phase csi:tt.csi --angles log.csv --baseline 0.06 -o out.yaml
    rfsas calibrate cal.yaml --array bleiq:tt.btsnoop?elements=8 --geometry uca:8,0.07 \
        --angles log.csv -o out.yaml
    """
    console = Console(stderr=as_json)
    array = {key: phase.pop(key) for key in ARRAY_KEYS}
    recordings = [
        spec.partition(":")[2].partition("?")[0]
        for spec in (phase["phase_capture"], array["array_capture"])
        if spec is not None
    ]
    sources: list[str | Path] = [
        *inputs,
        *[p for p in (capture, angles_path) if p is not None],
        *[r for r in recordings if r],
    ]
    for path in (output, plot_path):
        if path is not None:
            check_output(path, sources, force=force)
    if output is not None and plot_path is not None and output.resolve() == plot_path.resolve():
        raise click.UsageError("-o and --plot name the same file")
    if as_json and not check:
        raise click.UsageError("--json goes with --check")
    if phase["phase_capture"] is not None and array["array_capture"] is not None:
        raise click.UsageError("--phase and --array are separate runs")
    if array["array_capture"] is not None:
        run_array(
            console, inputs, output, angles_path, emitter, phase["known_position"],
            phase["phase_pose"], **array,
        )  # fmt: skip
        return
    if phase["phase_capture"] is not None:
        run_phase(console, inputs, output, angles_path, emitter, single_table, **phase)
        return
    if check:
        if len(inputs) != 2:
            raise click.UsageError("--check takes CAL.yaml SAMPLES.csv")
        cal = load_calibration(inputs[0])
        samples, dropped = drop_sentinels(read_samples_csv(inputs[1]))
        if dropped:
            _warn([Finding("warning", str(inputs[1]), f"{dropped} rows with sentinel readings "
                           "(−128 dBm, out of range) left out of the check")])  # fmt: skip
        _warn(raise_on_errors(check_samples(samples, str(inputs[1])), "check data"))
        report = check_calibration(cal, samples)
        if report.few_samples:
            rough = f"only {report.valid} bearings (under {MIN_FLOOR_SAMPLES}): rough floor, ratios"
            _warn([Finding("warning", str(inputs[1]), rough)])
        if as_json:
            click.echo(json.dumps(check_record(report, inputs[0], inputs[1])))
        else:
            console.print(_check_table(report, inputs[0], inputs[1]))
        if report.nothing_to_check:
            raise WorkFailed(f"nothing to check: no sample of {inputs[1]} gave a bearing")
        if output is not None:
            save_calibration(with_environment_floor(cal, report), output)
            console.print(f"calibration with the measured environment floor written to {output}")
        if plot_path is not None:
            plot_calibration(cal, samples, plot_path)
            console.print(f"plot written to {plot_path}")
        if not report.consistent:
            raise WorkFailed(
                f"{inputs[0]} is NOT consistent with {inputs[1]}: " + "; ".join(report.problems())
            )
        return
    if capture is not None:
        if inputs or angles_path is None or emitter is None:
            raise click.UsageError("--capture needs --angles LOG.csv and --emitter MAC, no INPUTS")
        from rfsas_hw.sources.turntable import samples_from_capture

        samples, joined = samples_from_capture(capture, angles_path, emitter)
        console.print(
            f"{joined.samples} samples from {joined.emitter_frames} frames of {emitter} "
            f"({joined.outside_log} outside the angle log, {joined.in_log_gap} in log gaps, "
            f"{joined.missing_antenna} without both antennas)"
        )
        source_name = Path(capture).name
    elif len(inputs) != 1:
        raise click.UsageError("give one samples CSV (or --check CAL.yaml SAMPLES.csv)")
    else:
        samples = read_samples_csv(inputs[0])
        source_name = inputs[0].name
    if output is None:
        raise click.UsageError("-o/--output CAL.yaml is required")
    source = str(capture) if capture is not None else str(inputs[0])
    _warn(raise_on_errors(check_samples(samples, source, noise_floor), "sweep"))
    cal = fit_calibration(
        samples,
        mode,  # type: ignore[arg-type]
        per_channel=not single_table,
        grid_step_deg=grid_step,
        step_db=step_db,
        noise_floor_dbm=noise_floor,
        antenna={"description": antenna, "source": source_name}
        if antenna
        else {"source": source_name},
    )
    _warn(raise_on_errors(validate_calibration(cal, f"fit of {source}"), "calibration"))
    save_calibration(cal, output)
    console.print(_summary(cal, output))
    if plot_path is not None:
        plot_calibration(cal, samples, plot_path)
        console.print(f"plot written to {plot_path}")
