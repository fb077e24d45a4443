"""SUMO closed loop through libsumo: RF-SAS stops the car for a pedestrian it cannot see.

Over 20 seeds (SUMO's seed, the bridge's seed and the pedestrian's walking
speed change together): the car that ignores RF-SAS hits the hidden
pedestrian in nearly every seed; braking on RF-SAS advisories avoids the
collision in at least 90 % of seeds and any remaining hit is much slower; a
pedestrian walking away from the road never draws a BRAKE.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

pytest.importorskip("libsumo", reason="needs the sumo extra: pip install 'rfsas-hw[sumo]'")

from rfsas_hw.bridges.sumo import SumoAdapter, load_sumo, read_buildings
from rfsas_hw.bridges.sumo_run import load_run_file, run_seed, run_seeds
from rfsas_hw.errors import ConfigError, SimulationError

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "sumo"
SEEDS = range(20)


@pytest.fixture(scope="module")
def run_file() -> tuple[object, object]:
    return load_run_file(EXAMPLE / "units.yaml")


@pytest.mark.slow
def test_closed_loop_over_20_seeds(run_file: tuple[object, object], tmp_path: Path) -> None:
    cfg, run = run_file
    crossing = EXAMPLE / "crossing.sumocfg"
    blind = run_seeds(crossing, cfg, run, SEEDS, controller="off")  # type: ignore[arg-type]
    assert blind.collisions >= 18
    assert blind.row()["collisions"] == blind.collisions  # no warning without bridge times
    base_speed = min(blind.impact_speeds())
    assert base_speed > 12.0
    out = tmp_path / "run.jsonl"
    with out.open("w") as f:
        rfsas = run_seeds(crossing, cfg, run, SEEDS, controller="rfsas", out=f)  # type: ignore[arg-type]
    assert rfsas.collisions <= 2
    assert all(s < 0.5 * base_speed for s in rfsas.impact_speeds())
    assert rfsas.brakes == len(SEEDS)
    assert all(r.fixes_ok > 20 and r.median_fix_error_m < 3.0 for r in rfsas.results)
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    assert sum(x["record"] == "seed" for x in lines) == len(SEEDS)
    assert any(x["record"] == "step" and x["action"] == "brake" for x in lines)


@pytest.mark.slow
def test_pedestrian_walking_away_draws_no_brake(run_file: tuple[object, object]) -> None:
    cfg, run = run_file
    away = run_seeds(EXAMPLE / "walk-away.sumocfg", cfg, run, SEEDS, controller="rfsas")  # type: ignore[arg-type]
    assert away.collisions == 0
    assert away.brakes == 0
    assert all(r.fixes_ok > 0 for r in away.results)


def test_adapter_moves_the_front_bumper_to_the_box_centre(run_file: tuple[object, object]) -> None:
    cfg, _ = run_file
    sumo = load_sumo("libsumo")
    sumo.start(["sumo", "-c", str(EXAMPLE / "crossing.sumocfg"), "--no-step-log", "true"])
    try:
        adapter = SumoAdapter(sumo, "ego", origin=cfg.origin_m)  # type: ignore[attr-defined]
        buildings = read_buildings(sumo, cfg.origin_m)  # type: ignore[attr-defined]
        for _ in range(95):
            sumo.simulationStep()
        ego, others = adapter.read()
        assert ego is not None
        _, fy = sumo.vehicle.getPosition("ego")
        # northbound lane centre 1.6 m east of the junction; SUMO reports the front bumper
        assert ego.x_m == pytest.approx(1.6, abs=1e-6)
        assert ego.y_m == pytest.approx(fy - 100.0 - 2.25, abs=1e-6)
        assert ego.heading_deg == pytest.approx(0.0, abs=1e-6)
        ped = next(o for o in others if o.id == "person:ped")
        px, py = sumo.person.getPosition("ped")
        assert (ped.x_m, ped.y_m) == pytest.approx((px - 100.0, py - 100.0))
        assert ped.kind == "pedestrian"
    finally:
        sumo.close()
    assert sorted(b.name for b in buildings) == ["bldg-ne", "bldg-nw", "bldg-se", "bldg-sw"]
    sw = next(b for b in buildings if b.name == "bldg-sw")
    assert (sw.x_min_m, sw.x_max_m, sw.y_min_m, sw.y_max_m) == (-60.0, -8.0, -60.0, -8.0)


def test_bad_inputs(run_file: tuple[object, object], tmp_path: Path) -> None:
    cfg, run = run_file
    bad = tmp_path / "run.yaml"
    bad.write_text("units: []\nsumo: {ego: e, brake: 1}\n")
    with pytest.raises(ConfigError, match="sumo: unknown key 'brake'"):
        load_run_file(bad)
    with pytest.raises(SimulationError, match="never appeared"):
        from dataclasses import replace

        run_seed(EXAMPLE / "crossing.sumocfg", cfg, replace(run, ego="nobody", end_s=2.0), 0)  # type: ignore[arg-type, type-var]
    with pytest.raises(SimulationError, match="did not start"):
        run_seed(tmp_path / "missing.sumocfg", cfg, run, 0)  # type: ignore[arg-type]


@pytest.mark.skipif(shutil.which("sumo") is None, reason="TraCI needs a sumo binary on PATH")
def test_traci_gives_what_libsumo_gives(run_file: tuple[object, object]) -> None:
    cfg, run = run_file
    crossing = EXAMPLE / "crossing.sumocfg"
    a = run_seed(crossing, cfg, run, 3, api="libsumo")  # type: ignore[arg-type]
    b = run_seed(crossing, cfg, run, 3, api="traci")  # type: ignore[arg-type]
    for name in ("collision", "first_brake_s", "first_caution_s", "fixes_ok", "steps"):
        assert getattr(a, name) == getattr(b, name), name
    assert a.min_gap_m == pytest.approx(b.min_gap_m, abs=1e-6)
