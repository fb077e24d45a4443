"""``rfsas sumo``: RF-SAS closed loop inside SUMO, and SUMO's FCD output as a twin scenario."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import IO, TYPE_CHECKING, cast

import click
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    ProgressColumn,
    TextColumn,
    TimeElapsedColumn,
)
from rich.table import Table

from rfsas_hw.cli.exitcodes import WorkFailed
from rfsas_hw.cli.options import keys_option, out_option, runner_options
from rfsas_hw.cli.outopts import OutputPath
from rfsas_hw.errors import ConfigError
from rfsas_hw.outpaths import check_output

if TYPE_CHECKING:
    from rfsas_hw.bridges.sumo_run import Controller, SeedResult

EXAMPLE_DIR = Path(__file__).resolve().parents[2] / "examples" / "sumo"
"""The bundled SUMO scenario (in a source checkout)."""
MAX_SEEDS = 10_000
"""The most seeds one ``sumo run`` takes (each is a full SUMO run)."""
RUN_FILE = "units.yaml"
"""The run file looked for next to a SUMO configuration when ``--units`` is not given."""


@click.group()
def sumo() -> None:
    """RF-SAS inside SUMO: closed loop over seeds, and FCD output to twin scenarios."""


def _fmt(x: float | None, digits: int = 2) -> str:
    return "—" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


@sumo.command()
@click.argument(
    "net_or_sumocfg",
    required=False,
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
)
@click.option("--ego", default=None, help="SUMO id of the ego vehicle (default: the run file's).")
@click.option(
    "--units",
    "units_path",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    default=None,
    help=f"Run file: units, devices, backend profile, sumo: section (default: {RUN_FILE} "
    "next to the SUMO file).",
)
@click.option("--seeds", default=1, show_default=True, type=click.IntRange(1), help="Seeds to run.")
@click.option("--first-seed", default=0, show_default=True, type=int, help="First seed.")
@click.option(
    "--controller",
    type=click.Choice(["rfsas", "ignore", "off"]),
    default="rfsas",
    show_default=True,
    help="rfsas: advisories steer the ego; ignore: RF-SAS runs, the ego ignores it; "
    "off: no RF-SAS.",
)
@click.option(
    "--api",
    type=click.Choice(["libsumo", "traci"]),
    default=None,
    help="libsumo (in-process, default) or traci (default with --gui).",
)
@click.option("--gui", is_flag=True, help="Watch in sumo-gui (TraCI).")
@out_option("JSON lines: every step (hashed ids only) and every seed's result.")
@click.option(
    "--truth",
    type=OutputPath(),
    default=None,
    help="Truth file (entity, device, MAC, emitter id); one per seed with -seedN in its name.",
)
@click.option(
    "--fcd",
    type=OutputPath(),
    default=None,
    help="SUMO FCD output of the first seed (for 'rfsas sumo fcd').",
)
@click.option(
    "--send",
    metavar="URL",
    default=None,
    help="Also send every unit's signed bearings to a separate 'rfsas backend' (e.g. "
    "udp://127.0.0.1:47000); paces the run to the wall clock (needs --keys).",
)
@keys_option(
    "One sensor key directory per unit id, named by it (rfsas keys new --role sensor "
    "--id ID -o KEYS/ID), for --send; the ego's own unit is 'ego-unit' unless the run "
    "file names it otherwise.",
    required=False,
)
@runner_options(what="seeds")
@click.option("--force", is_flag=True, help="Replace existing output files (never an input).")
def run(
    net_or_sumocfg: Path | None,
    ego: str | None,
    units_path: Path | None,
    seeds: int,
    first_seed: int,
    controller: str,
    api: str | None,
    gui: bool,
    out: Path | None,
    truth: Path | None,
    fcd: Path | None,
    send: str | None,
    keys_dir: Path | None,
    workers: int | None,
    scheduler: str | None,
    force: bool,
) -> None:
    """Run NET_OR_SUMOCFG closed loop with RF-SAS (default: the bundled crossing).

    Several seeds run side by side on a local Dask cluster (or --scheduler); the results
    do not depend on the number of workers."""
    from rfsas_hw.bridges.sumo_run import Controller, load_run_file, run_seeds
    from rfsas_hw.bridges.sumofiles import sumo_inputs
    from rfsas_hw.parallel import default_workers

    cfg_path = net_or_sumocfg or EXAMPLE_DIR / "crossing.sumocfg"
    if not cfg_path.exists():
        raise ConfigError(f"{cfg_path}: no such SUMO file (give NET_OR_SUMOCFG)")
    units_file = units_path or cfg_path.parent / RUN_FILE
    if not units_file.exists():
        raise ConfigError(f"{units_file}: no run file; give --units")
    if seeds > MAX_SEEDS:
        raise ConfigError(f"--seeds {seeds}: at most {MAX_SEEDS} in one run")
    inputs = [*sumo_inputs(cfg_path), units_file]
    truths = {
        seed: truth.with_name(f"{truth.stem}-seed{seed}{truth.suffix}")
        for seed in range(first_seed, first_seed + seeds)
        if truth is not None
    }
    if truth is not None:  # the per-seed names derive from it: it must not name an input
        check_output(truth, inputs, force=True, what="--truth")
    for option, target in (("--truth", truth), ("--fcd", fcd)):
        if target is not None and target.exists() and not target.is_file():
            # SUMO writes the FCD itself, and per-seed truth names sit beside the
            # given one: only a file can be checked afterwards
            raise ConfigError(f"{option} {target}: name a file, not a device or directory")
    for target in (out, fcd, *truths.values()):
        if target is not None:
            check_output(target, inputs, force=force)
    bridge_cfg, run_cfg = load_run_file(units_file)
    if ego is not None:
        run_cfg = dataclasses.replace(run_cfg, ego=ego)
    chosen_api = api or ("traci" if gui else "libsumo")
    ctl = cast(Controller, controller)
    seed_list = list(range(first_seed, first_seed + seeds))
    here = gui or send is not None
    if workers is None:
        workers = default_workers(len(seed_list), here=here or scheduler is not None)
    local = workers == 0 and scheduler is None
    if here and not local:
        raise ConfigError("--gui and --send run here: not with --workers > 0 or --scheduler")
    results: list[SeedResult] = []
    sink: IO[str] | None = None
    if out is not None:
        try:
            sink = out.open("w", encoding="utf-8")
        except OSError as err:
            raise ConfigError(f"{out}: cannot write: {err.strerror or err}") from err
    if local:  # one seed at a time: a bar of each seed's simulation time
        columns: tuple[ProgressColumn, ...] = (
            TextColumn("seed {task.fields[seed]}"),
            BarColumn(),
            TextColumn("{task.completed:.1f}/{task.total:.0f} s"),
            TimeElapsedColumn(),
        )
    else:  # seeds side by side: a bar of seeds done
        columns = (TextColumn("seeds"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    try:
        with Progress(*columns, transient=True) as bar:
            total = run_cfg.end_s if local else len(seed_list)
            task = bar.add_task("sumo", total=total, seed=first_seed)

            def on_step(seed: int, t: float) -> None:
                bar.update(task, completed=min(t, run_cfg.end_s), seed=seed)

            def on_seed(r: SeedResult) -> None:
                if not local:
                    bar.update(task, advance=1)

            summary = run_seeds(
                cfg_path, bridge_cfg, run_cfg, seed_list, controller=ctl,
                api=chosen_api,  # type: ignore[arg-type]
                out=sink, on_seed=on_seed, truth_paths=truths, fcd_path=fcd,
                workers=workers, scheduler=scheduler, on_step=on_step if local else None,
                gui=gui, send=send, keys_dir=keys_dir,
            )  # fmt: skip
            results = summary.results
    finally:
        if sink is not None:
            sink.close()
    _summary(cfg_path, ctl, results)
    if send is not None:
        sent = sum(r.sent for r in results)
        Console().print(f"sent {sent:,} bearings to {send}", highlight=False)
        problems = [p for r in results for p in r.send_problems]
        if problems:
            raise WorkFailed("; ".join(dict.fromkeys(problems)))


def _summary(cfg_path: Path, controller: str, results: list[SeedResult]) -> None:
    from rfsas_hw.bridges.sumo_run import RunSummary

    summary = RunSummary(cast("Controller", controller), results)
    table = Table(title=f"{cfg_path.name}: controller {controller}")
    for col in (
        "seed",
        "collision",
        "VRU class",
        "impact m/s",
        "min gap m",
        "first caution s",
        "first brake s",
        "fixes ok",
        "fix error m",
        "SUMO ms/step",
        "bridge ms/step",
    ):
        table.add_column(col, justify="right")
    for r in summary.results:
        table.add_row(
            str(r.seed),
            "yes" if r.collision else "no",
            r.collision_class or "—",
            _fmt(r.impact_speed_mps, 1),
            _fmt(r.min_gap_m),
            _fmt(r.first_caution_s, 1),
            _fmt(r.first_brake_s, 1),
            str(r.fixes_ok),
            _fmt(r.median_fix_error_m),
            _fmt(r.sumo_ms, 3),
            _fmt(r.bridge_ms),
        )
    console = Console()
    console.print(table)
    row = summary.row()
    console.print(
        f"{row['seeds']} seeds: {row['collisions']} collisions{_by_class(row)} "
        f"(mean impact {row['mean_impact_mps']:.1f} m/s, max {row['max_impact_mps']:.1f}), "
        f"BRAKE in {row['seeds_with_brake']} seeds (median first at "
        f"{_fmt(row['median_first_brake_s'], 1)} s), median min gap "
        f"{_fmt(row['median_min_gap_m'])} m, {row['fixes_ok']} fixes "
        f"(median error {_fmt(row['median_fix_error_m'])} m); per step SUMO "
        f"{_fmt(row['sumo_ms'], 3)} ms, RF-SAS {_fmt(row['bridge_ms'])} ms"
    )


def _by_class(row: dict[str, object]) -> str:
    """`` (bicycle 1, pedestrian 2)``: the collisions per VRU class ('' without any)."""
    counts = cast("dict[str, int]", row["collisions_by_class"])
    if not counts:
        return ""
    return " (" + ", ".join(f"{k} {n}" for k, n in sorted(counts.items())) + ")"


@sumo.command(name="fcd")
@click.argument("fcd_path", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option(
    "--units",
    "units_path",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    required=True,
    help="Run file (units, devices, seed, origin).",
)
@click.option("--ego", default=None, help="SUMO id of the ego vehicle (default: the run file's).")
@click.option(
    "--poly",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    default=None,
    help="SUMO polygon file whose 'building' polygons become buildings.",
)
@out_option(
    "Scenario YAML to write (then: rfsas sim capture SCENARIO -o DIR).",
    dest="output",
    required=True,
)
def fcd_command(
    fcd_path: Path, units_path: Path, ego: str | None, poly: Path | None, output: Path
) -> None:
    """Turn SUMO's FCD output into a twin scenario with the run file's units and devices."""
    from rfsas_hw.bridges.fcd import buildings_from_poly_file, fcd_to_scenario, write_scenario
    from rfsas_hw.bridges.sumo_run import load_run_file

    bridge_cfg, run_cfg = load_run_file(units_path)
    buildings = buildings_from_poly_file(poly, bridge_cfg.origin_m) if poly is not None else []
    data = fcd_to_scenario(
        fcd_path, bridge_cfg, ego=ego or run_cfg.ego, buildings=buildings, name=fcd_path.stem
    )
    write_scenario(data, output)
    Console().print(
        f"{output}: {len(data['movers'])} movers, {len(data['emitters'])} emitters, "
        f"{len(data['sensors'])} units, {data['duration_s']:.1f} s"
    )
