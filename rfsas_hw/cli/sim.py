"""``rfsas sim``: the digital twin: captures from a scenario, turntable runs, the braking case."""

from __future__ import annotations

from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from rfsas_hw.df import save_calibration
from rfsas_hw.sim.capture_writer import write_captures
from rfsas_hw.sim.scenario import load_scenario
from rfsas_hw.sim.turntable import turntable_calibration
from rfsas_hw.sim.world import World


@click.group()
def sim() -> None:
    """Digital twin: scenarios that produce real captures, and the braking case."""


@sim.command()
@click.argument("scenario", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "-o",
    "--output",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="Directory for the captures and truth.jsonl.",
)
@click.option(
    "--format",
    "fmt",
    type=click.Choice(["pcap", "pcapng"]),
    default="pcap",
    show_default=True,
    help="Capture file format.",
)
@click.option(
    "--detail",
    type=click.Choice(["low", "medium", "high"]),
    default=None,
    help="Override the scenario's level of detail.",
)
def capture(scenario: Path, out_dir: Path, fmt: str, detail: str | None) -> None:
    """Write one radiotap capture per receiver card of SCENARIO, plus the ground truth."""
    world = World(load_scenario(scenario), detail)  # type: ignore[arg-type]
    result = write_captures(world, out_dir, fmt)  # type: ignore[arg-type]
    table = Table(
        title=f"{world.scenario.spec.name}: {world.duration_s:g} s, "
        f"seed {world.scenario.seed}, {world.detail} detail"
    )
    table.add_column("sensor")
    table.add_column("file")
    table.add_column("frames", justify="right")
    for sensor_id, files in result.files.items():
        for path, frames in zip(files, result.frames[sensor_id], strict=True):
            table.add_row(sensor_id, str(path), str(frames))
    for sensor_id, path in result.board_streams.items():
        table.add_row(sensor_id, str(path), str(result.frames[sensor_id][0]))
    if result.truth is not None:
        table.add_row("ground truth", str(result.truth), "")
    Console().print(table)


@sim.command()
@click.argument("scenario", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--sensor", "sensors", multiple=True, help="Only this sensor (repeatable).")
@click.option(
    "--mode",
    type=click.Choice(["linear", "db"]),
    default="linear",
    show_default=True,
    help="Monopulse ratio mode of the fitted tables.",
)
def turntable(scenario: Path, sensors: tuple[str, ...], mode: str) -> None:
    """Calibrate SCENARIO's sensors on a simulated turntable; write their calibration files."""
    sc = load_scenario(scenario)
    for s in sc.spec.sensors:
        if sensors and s.id not in sensors:
            continue
        path = sc.calibration_path(s.id)
        if path is None:
            click.echo(f"{s.id}: no calibration file named in the scenario; skipped")
            continue
        cal = turntable_calibration(sc, s.id, mode=mode)  # type: ignore[arg-type]
        path.parent.mkdir(parents=True, exist_ok=True)
        save_calibration(cal, path)
        t = cal.tables[0]
        click.echo(
            f"{s.id}: {path} (FoV {t.fov_deg[0]:+.1f}°…{t.fov_deg[1]:+.1f}°, "
            f"residual {t.residual_rms_deg:.2f}°)"
        )
