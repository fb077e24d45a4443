"""``rfsas sim``: the digital twin: captures from a scenario, turntable runs, the braking case."""

from __future__ import annotations

import json
from pathlib import Path
from typing import cast

import click
from rich.console import Console
from rich.table import Table

from rfsas_hw.cli.options import json_option, out_option
from rfsas_hw.cli.outopts import OutputPath
from rfsas_hw.df import save_calibration
from rfsas_hw.errors import ConfigError
from rfsas_hw.outpaths import check_output, inside
from rfsas_hw.studies.braking import BrakingCase, plot_braking, run_braking
from rfsas_hw.twin.capture_writer import TRUTH_FILE, card_file_names, write_captures
from rfsas_hw.twin.scenario import Detail, load_scenario
from rfsas_hw.twin.turntable import turntable_calibration
from rfsas_hw.twin.world import World


@click.group()
def sim() -> None:
    """Digital twin: scenarios that produce real captures, and the braking case."""


@sim.command()
@click.argument("scenario", type=click.Path(dir_okay=False, path_type=Path))
@out_option(
    "Directory for the captures and truth.jsonl.",
    dest="out_dir",
    kind="dir",
    required=True,
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
@click.option("--force", is_flag=True, help="Replace capture files already in the directory.")
def capture(scenario: Path, out_dir: Path, fmt: str, detail: str | None, force: bool) -> None:
    """Write one radiotap capture per receiver card of SCENARIO, plus the ground truth."""
    world = World(load_scenario(scenario), detail)  # type: ignore[arg-type]
    for name in capture_names(world, fmt):
        check_output(inside(out_dir, name), [scenario], force=force)
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


def capture_names(world: World, fmt: str) -> list[str]:
    """The file names :func:`write_captures` will create for ``world``."""
    names = [TRUTH_FILE]
    for s in world.scenario.spec.sensors:
        if s.receiver == "serial-board":
            names.append(f"{s.id}.board.bin")
        else:
            names += card_file_names(s.id, s.n_cards, fmt)  # type: ignore[arg-type]
    return names


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
@click.option(
    "--force", is_flag=True, help="Replace calibration files that exist (refused otherwise)."
)
def turntable(scenario: Path, sensors: tuple[str, ...], mode: str, force: bool) -> None:
    """Calibrate SCENARIO's sensors on a simulated turntable; write the calibration files the
    scenario names (an existing one only with --force; never the scenario itself)."""
    sc = load_scenario(scenario)
    chosen = [s for s in sc.spec.sensors if not sensors or s.id in sensors]
    paths = {s.id: sc.calibration_path(s.id) for s in chosen}
    for sid, path in paths.items():  # refuse before anything is written
        if path is not None:
            # a scenario file names where its tables go: only beside it, never elsewhere
            inside(sc.base_dir, str(sc.sensor(sid).calibration))
            check_output(path, [scenario], force=force, what="calibration file")
    for s in chosen:
        path = paths[s.id]
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


@sim.command()
@click.option(
    "--speed", "speed_mps", type=float, default=20.0, show_default=True, help="Initial speed, m/s."
)
@click.option(
    "--start",
    "start_m",
    type=float,
    default=-100.0,
    show_default=True,
    help="Vehicle centre at t = 0, metres north of the intersection centre.",
)
@click.option(
    "--delay",
    "delay_s",
    type=float,
    default=1.5,
    show_default=True,
    help="Reaction delay before braking (scan + message + computation), s.",
)
@click.option(
    "--detail",
    type=click.Choice(["low", "medium", "high"]),
    default="high",
    show_default=True,
    help="Level of detail of the twin that locates the pedestrian.",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Scenario seed.")
@click.option(
    "--plot",
    "plot_path",
    type=OutputPath(),
    help="Draw gap, speed and P_coll over time to this PNG.",
)
@json_option("Print one JSON object.")
def braking(
    speed_mps: float,
    start_m: float,
    delay_s: float,
    detail: str,
    seed: int,
    plot_path: Path | None,
    as_json: bool,
) -> None:
    """The paper's braking case: brake at 0.47 g after the delay, against a located pedestrian."""
    try:
        case = BrakingCase(
            speed_mps=speed_mps,
            start_m=start_m,
            delay_s=delay_s,
            detail=cast(Detail, detail),
            seed=seed,
        )
    except ValueError as err:
        raise ConfigError(f"braking case: {err}") from err
    result = run_braking(case)
    if plot_path is not None:
        plot_braking(result, str(plot_path))
    summary = result.summary()
    if as_json:
        click.echo(json.dumps(summary))
        return
    table = Table(
        title=f"Braking at 0.47 g: {speed_mps:g} m/s from {start_m:g} m, delay {delay_s:g} s"
    )
    table.add_column("quantity")
    table.add_column("value", justify="right")
    table.add_row("stops before the pedestrian", "yes" if result.stopped else "no")
    table.add_row(
        "gap at rest" if result.stopped else "distance short", f"{abs(result.gap_at_rest_m):.1f} m"
    )
    table.add_row(
        "impact speed",
        f"{result.impact_speed_mps:.2f} m/s ({result.impact_speed_mps * 3.6:.1f} km/h)",
    )
    table.add_row("P_collision", f"{result.p_collision:.4f}")
    table.add_row("P_fatality", f"{result.p_fatality:.4f}")
    table.add_row("risk", f"{result.risk:.5f}")
    fx, fy = summary["fix_xy_m"]
    sx, sy = summary["fix_sigma_m"]
    table.add_row(
        "pedestrian located at",
        f"({fx:.1f}, {fy:.1f}) m ± ({sx:.1f}, {sy:.1f}) m [{summary['fix_status']}]",
    )
    ox, oy = summary["obstacle_xy_m"]
    table.add_row("pedestrian truly at", f"({ox:.1f}, {oy:.1f}) m")
    if plot_path is not None:
        table.add_row("plot", str(plot_path))
    Console().print(table)


# learning to brake (train / evaluate / render) lives in its own module
from rfsas_hw.cli.simrl import evaluate as _evaluate  # noqa: E402
from rfsas_hw.cli.simrl import render as _render  # noqa: E402
from rfsas_hw.cli.simrl import train as _train  # noqa: E402

for _command in (_train, _evaluate, _render):
    sim.add_command(_command)

from rfsas_hw.cli.simcue import cueing as _cueing  # noqa: E402

sim.add_command(_cueing)
