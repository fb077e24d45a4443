"""District demand from SUMO's randomTrips.py, with phones and reckless VRUs drawn per VRU."""

from __future__ import annotations

import subprocess
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import pytest

pytest.importorskip("sumo", reason="needs the city extra: pip install 'rfsas-hw[city]'")
pytest.importorskip("sumolib", reason="needs the city extra: pip install 'rfsas-hw[city]'")

from rfsas_hw.city.demand import DemandConfig, generate, read_vru_table
from rfsas_hw.city.net import sumo_binary, sumo_env
from rfsas_hw.errors import ConfigError, SimulationError

SMALL = DemandConfig(vehicles=20, pedestrians=30, bicycles=10, end_s=60.0)


def test_demand_is_seeded_and_carries_the_vru_table(
    grid_net: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    elsewhere = tmp_path / "cwd"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    a = generate(grid_net, tmp_path / "a", SMALL, seed=5)
    b = generate(grid_net, tmp_path / "b", SMALL, seed=5)
    assert list(elsewhere.iterdir()) == []  # nothing left where the caller stood
    assert [p.name for p in a.route_files] == [
        "vehicles.rou.xml",
        "pedestrians.rou.xml",
        "bicycles.rou.xml",
    ]
    assert a.vrus == b.vrus and a.vehicles == b.vehicles
    assert len(a.vehicles) == 20
    classes = sorted(r.vru_class for r in a.vrus.values())
    assert classes.count("pedestrian") == 30 and classes.count("bicycle") == 10
    assert read_vru_table(a.table) == a.vrus
    for r in a.vrus.values():
        assert (r.device_model is not None) == r.has_phone
        assert 0.0 <= r.depart_s < 60.0
    # every person's and bicycle's vType says whether it is reckless
    people = ET.parse(a.route_files[1]).getroot()
    for p in people.iter("person"):
        want = "ped-reckless" if a.vrus[p.get("id", "")].reckless else "ped"
        assert p.get("type") == want
    assert {t.get("id") for t in people.iter("vType")} <= {"ped", "ped-reckless"}


def test_shares_at_their_limits(grid_net: Path, tmp_path: Path) -> None:
    cfg = DemandConfig(
        vehicles=0,
        pedestrians=20,
        bicycles=0,
        end_s=40.0,
        phone_penetration=0.0,
        reckless_share=1.0,
    )
    d = generate(grid_net, tmp_path, cfg, seed=1)
    assert len(d.route_files) == 1 and d.vehicles == ()
    assert all(r.reckless and not r.has_phone for r in d.vrus.values())


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"device_mix": {"walkie-talkie": 1.0}}, "unknown model"),
        ({"phone_penetration": 1.5}, "phone_penetration"),
        ({"end_s": 0.0}, "end_s"),
        ({"pedestrians": -1}, "pedestrians"),
    ],
)
def test_bad_demand_settings_are_refused(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        DemandConfig(**kwargs)  # type: ignore[arg-type]


def test_a_bad_vru_table_names_the_line(tmp_path: Path) -> None:
    f = tmp_path / "vrus.csv"
    f.write_text("id,class,has_phone,device_model,reckless,depart_s\np1,horse,1,x,0,1.0\n")
    with pytest.raises(ConfigError, match="line 2"):
        read_vru_table(f)


def test_reckless_pedestrians_cross_against_the_light(grid_net: Path, tmp_path: Path) -> None:
    """Same trips, all careful vs all reckless: on a grid of traffic lights careful
    pedestrians wait at red crossings, reckless ones hardly wait."""
    waits = {}
    for share in (0.0, 1.0):
        cfg = DemandConfig(vehicles=0, pedestrians=40, bicycles=0, end_s=80, reckless_share=share)
        d = generate(grid_net, tmp_path / str(share), cfg, seed=3)
        info = tmp_path / f"trips{share}.xml"
        cmd = [str(sumo_binary("sumo")), "-n", str(grid_net), "-r", str(d.route_files[0])]
        cmd += ["--tripinfo-output", str(info), "--no-step-log", "-e", "1000"]
        subprocess.run(cmd, env=sumo_env(), check=True, capture_output=True, timeout=120)
        walks = [float(w.get("waitingTime", "nan")) for w in ET.parse(info).iter("walk")]
        assert len(walks) == 40
        waits[share] = sum(walks) / len(walks)
    assert waits[0.0] > 5.0
    assert waits[1.0] < waits[0.0] / 5


def test_a_net_too_small_for_any_car_trip_is_an_error_not_a_district_without_cars(
    grid_factory: Callable[[int, float], Path], tmp_path: Path
) -> None:
    # 100 m between junctions, 60 m stubs: no two edges 300 m apart (the car trips' minimum)
    small = grid_factory(2, 100.0)
    cfg = DemandConfig(vehicles=3, pedestrians=4, bicycles=0, end_s=20.0)
    with pytest.raises(SimulationError, match=r"grid2\.net\.xml: none of the 3 vehicle trips"):
        generate(small, tmp_path / "demand", cfg, seed=1)
    walkers = generate(small, tmp_path / "walkers", replace(cfg, vehicles=0), seed=1)
    assert len(walkers.vrus) == 4
