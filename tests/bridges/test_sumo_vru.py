"""Every VRU counts: `rfsas sumo run` scores two-wheelers as well as persons, box against box."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from rfsas_hw.bridges.boxes import box_distance, corners, overlap
from rfsas_hw.bridges.bridge import Entity
from rfsas_hw.bridges.vru_score import vru_class

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "sumo"


def _car(x: float = 0.0, y: float = 0.0, heading: float = 0.0) -> Entity:
    return Entity("car", "vehicle", x, y, heading, 10.0, 4.5, 1.8)


def test_corners_follow_the_compass_heading() -> None:
    east = corners(_car(heading=90.0))
    xs = sorted(round(x, 9) for x, _ in east)
    ys = sorted(round(y, 9) for _, y in east)
    assert xs == [-2.25, -2.25, 2.25, 2.25]
    assert ys == [-0.9, -0.9, 0.9, 0.9]


def test_box_distance_of_oriented_boxes() -> None:
    car = _car()
    # a bicycle 1 m right of the car's right side, parallel
    bike = Entity("b", "cyclist", 0.9 + 1.0 + 0.3, 0.0, 0.0, 5.0, 1.9, 0.6)
    assert box_distance(car, bike) == pytest.approx(1.0)
    assert not overlap(car, bike)
    # turned by 45 degrees, its nearest corner is closer than its centre line
    turned = Entity("b", "cyclist", 2.2, 0.0, 45.0, 5.0, 1.9, 0.6)
    reach = (1.9 / 2) * math.sin(math.radians(45)) + 0.3 * math.cos(math.radians(45))
    assert box_distance(car, turned) == pytest.approx(2.2 - reach - 0.9)
    # overlapping at a corner only
    corner = Entity("p", "pedestrian", 1.0, 2.3, 0.0, 1.0, 0.5, 0.5)
    assert overlap(car, corner)
    assert box_distance(car, corner) == 0.0


def test_vru_classes() -> None:
    assert vru_class("pedestrian", None) == "pedestrian"
    assert vru_class("vehicle", "moped") == "moped"
    assert vru_class("vehicle", "motorcycle") == "motorcycle"
    assert vru_class("cyclist", "bicycle") == "bicycle"
    assert vru_class("vehicle", "passenger") is None


def _crossing(tmp_path: Path, vclass: str, speed: float) -> Path:
    """The bundled crossing with a two-wheeler riding east through the junction into the
    ego's path (it ignores the junction's rules), timed to meet the northbound ego."""
    ego_depart = 20.0
    # the ego (13.89 m/s) reaches the conflict point 98.4 m up its lane; the rider 101.6 m in
    depart = ego_depart + 98.4 / 13.89 - 101.6 / speed - 0.3
    routes = tmp_path / f"{vclass}.rou.xml"
    routes.write_text(
        f"""<routes>
  <vType id="car" vClass="passenger" length="4.50" width="1.80" maxSpeed="13.89" speedDev="0"
         sigma="0" accel="2.6" decel="4.6" emergencyDecel="9.0"/>
  <vType id="two" vClass="{vclass}" length="1.9" width="0.65" maxSpeed="{speed}" speedDev="0"
         sigma="0" jmIgnoreFoeProb="1" jmIgnoreFoeSpeed="100" jmIgnoreJunctionFoeProb="1"
         impatience="1"/>
  <vehicle id="rider" type="two" depart="{depart:.2f}" departPos="0" departSpeed="max">
    <route edges="left0A0 A0right0"/></vehicle>
  <vehicle id="ego" type="car" depart="{ego_depart}" departPos="0" departSpeed="max">
    <route edges="bottom0A0 A0top0"/></vehicle>
</routes>
""",
        encoding="utf-8",
    )
    cfg = tmp_path / f"{vclass}.sumocfg"
    cfg.write_text(
        f"""<configuration><input>
  <net-file value="{EXAMPLE / "crossing.net.xml"}"/><route-files value="{routes}"/>
</input><time><begin value="0"/><end value="40"/><step-length value="0.1"/></time>
</configuration>
""",
        encoding="utf-8",
    )
    return cfg


@pytest.mark.parametrize(("vclass", "speed"), [("bicycle", 5.0), ("moped", 10.0)])
def test_a_cyclist_and_a_moped_collision_are_reported(
    tmp_path: Path, vclass: str, speed: float
) -> None:
    pytest.importorskip("libsumo", reason="needs the sumo extra (pip install .[sumo])")
    from rfsas_hw.bridges.sumo_run import RunSummary, load_run_file, run_seed

    cfg, run = load_run_file(EXAMPLE / "units.yaml")
    r = run_seed(_crossing(tmp_path, vclass, speed), cfg, run, 0, controller="off")
    assert r.collision
    assert r.collision_class == vclass
    assert "boxes" in r.collision_seen_by and "sumo" in r.collision_seen_by
    assert r.impact_speed_mps == pytest.approx(13.89, abs=0.05)
    assert r.min_gap_by_class == {vclass: 0.0}
    assert r.as_dict()["min_gap_by_class"] == {vclass: 0.0}
    assert RunSummary("off", [r]).row()["collisions_by_class"] == {vclass: 1}


def test_a_rider_that_passes_ahead_is_a_gap_not_a_collision(tmp_path: Path) -> None:
    pytest.importorskip("libsumo", reason="needs the sumo extra (pip install .[sumo])")
    from rfsas_hw.bridges.sumo_run import load_run_file, run_seed

    cfg, run = load_run_file(EXAMPLE / "units.yaml")
    # the rider leaves 2.5 s earlier: it is through before the car arrives
    path = _crossing(tmp_path, "bicycle", 5.0)
    routes = path.with_suffix("").with_suffix(".rou.xml")
    text = routes.read_text()
    start = text.index('depart="', text.index('id="rider"')) + len('depart="')
    end = text.index('"', start)
    routes.write_text(text[:start] + f"{float(text[start:end]) - 2.5:.2f}" + text[end:])
    r = run_seed(path, cfg, run, 0, controller="off")
    assert not r.collision
    assert 0.0 < r.min_gap_by_class["bicycle"] < 15.0
