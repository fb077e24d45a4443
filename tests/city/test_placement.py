"""Roadside units at every signalised junction; buildings from polygons or city blocks."""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from pathlib import Path

import pytest

pytest.importorskip("sumo", reason="needs the city extra: pip install 'rfsas-hw[city]'")
pytest.importorskip("sumolib", reason="needs the city extra: pip install 'rfsas-hw[city]'")

from rfsas_hw.city.net import NetInfo, read_net
from rfsas_hw.city.placement import (
    BuildingOptions,
    buildings,
    load_placement,
    place_units,
    placed_units,
)
from rfsas_hw.errors import ConfigError
from rfsas_hw.link.topics import quadkey


@pytest.fixture(scope="module")
def info(grid_net: Path) -> NetInfo:
    return read_net(grid_net)


def test_two_units_on_opposite_corners_facing_each_junction(info: NetInfo) -> None:
    units = place_units(info)
    assert len(units) == 2 * 9
    by_junction: dict[str, list] = {}
    for u in units:
        by_junction.setdefault(u.junction, []).append(u)
    for jid, pair in by_junction.items():
        j = next(j for j in info.junctions if j.id == jid)
        a, b = pair
        # opposite corners: the junction's centre is the midpoint
        assert (a.x_m + b.x_m) / 2 == pytest.approx(j.x_m, abs=1e-6)
        assert (a.y_m + b.y_m) / 2 == pytest.approx(j.y_m, abs=1e-6)
        for u in pair:
            # on a diagonal of the (axis-aligned) grid to within a degree (SUMO rounds the
            # junction outline's corners), outside the junction, facing it
            dx, dy = j.x_m - u.x_m, j.y_m - u.y_m
            assert math.degrees(math.atan2(abs(dy), abs(dx))) == pytest.approx(45.0, abs=1.0)
            assert math.hypot(dx, dy) > 8.0
            facing = math.degrees(math.atan2(dx, dy)) % 360.0
            assert u.boresight_deg == pytest.approx(facing, abs=1e-6)
            lat, lon, _ = info.origin.to_geodetic(u.x_m, u.y_m)
            assert u.tile == quadkey(float(lat), float(lon))


def test_a_two_by_two_grid_gets_a_pair_per_junction(
    grid_factory: Callable[[int, float], Path],
) -> None:
    units = place_units(read_net(grid_factory(2, 200.0)))
    assert len(units) == 8
    assert len({u.junction for u in units}) == 4


def test_yaml_chooses_junctions_and_adds_units(info: NetInfo, tmp_path: Path) -> None:
    f = tmp_path / "units.yaml"
    f.write_text(
        "junctions: [B1]\nper_junction: 1\n"
        "units:\n  - {id: rsu-extra, x_m: 30.0, y_m: 40.0, boresight_deg: 90.0}\n"
    )
    units = place_units(info, load_placement(f))
    assert [u.id for u in units] == ["rsu-B1-0", "rsu-extra"]
    assert units[1].junction == "" and units[1].boresight_deg == 90.0
    f.write_text("units:\n  - {id: only, x_m: 1.0, y_m: 2.0, boresight_deg: 0.0}\nreplace: true\n")
    assert [u.id for u in place_units(info, load_placement(f))] == ["only"]


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("junctions: [nowhere]\n", "not a traffic-light program"),
        ("per_junction: 3\n", "per_junction"),
        ("setback: 2\n", "unknown key 'setback'"),
        ("units:\n  - {id: 'bad id', x_m: 0, y_m: 0, boresight_deg: 0}\n", "units"),
        ("replace: true\n", "no units: replace is true and units lists none"),
        ("junctions: []\n", "no units: junctions lists none"),
    ],
)
def test_bad_placement_yaml_names_the_problem(
    info: NetInfo, tmp_path: Path, text: str, match: str
) -> None:
    f = tmp_path / "units.yaml"
    f.write_text(text)
    with pytest.raises(ConfigError, match=match):
        place_units(info, load_placement(f))


def test_block_buildings_stay_off_every_lane(info: NetInfo) -> None:
    units = place_units(info)
    found = buildings(info, units)
    # the grid's four inner blocks are 120 m squares between the streets: each gets cells
    assert len(found) >= 4
    for b in found:
        for r in info.roads:
            for x, y in r.shape:
                inside = b.x_min_m - 3 < x < b.x_max_m + 3 and b.y_min_m - 3 < y < b.y_max_m + 3
                assert not inside, (b, r.edge)
    # the outer stubs do not enclose a block: nothing beyond the outer streets
    assert all(-120 < b.x_min_m and b.x_max_m < 120 for b in found)
    assert buildings(info, units, opts=BuildingOptions(near_m=1.0)) == []


def test_polygon_file_buildings_are_bounding_boxes_in_the_frame(
    info: NetInfo, tmp_path: Path
) -> None:
    poly = tmp_path / "district.poly.xml"
    # net coordinates: the frame is shifted by the net's centre (180, 180)
    poly.write_text(
        "<additional>\n"
        '  <poly id="b1" type="building" shape="200,200 230,200 230,220 200,220"/>\n'
        '  <poly id="park" type="park" shape="0,0 10,0 10,10"/>\n'
        "</additional>\n"
    )
    units = place_units(info)
    (b,) = buildings(info, units, polygons=poly)
    assert (b.x_min_m, b.x_max_m, b.y_min_m, b.y_max_m) == pytest.approx((20, 50, 20, 40))
    poly.write_text('<additional><poly id="x" type="building" shape="1,a"/></additional>')
    with pytest.raises(ConfigError, match="bad shape"):
        buildings(info, units, polygons=poly)


@pytest.mark.parametrize("shape", ["1,2 3", "1,2,3,4 5,6", "", "nan,1 2,3", "1;2 3;4"])
def test_a_bad_polygon_shape_names_its_line_and_poly(
    info: NetInfo, tmp_path: Path, shape: str
) -> None:
    poly = tmp_path / "bad.poly.xml"
    poly.write_text(f'<additional>\n<poly id="b7" type="building" shape="{shape}"/>\n</additional>')
    with pytest.raises(ConfigError, match=r"bad\.poly\.xml: line 2: poly 'b7': bad shape"):
        buildings(info, place_units(info), polygons=poly)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("units:\n  - {id: far, x_m: 5000, y_m: 0, boresight_deg: 0}\n", "'far' at x_m 5000"),
        ("units:\n  - {id: lost, x_m: .nan, y_m: 0, boresight_deg: 0}\n", "x_m: expected a number"),
        ("per_junction: 3\n", "per_junction must be 1 or 2"),
        ("junctions: [nowhere]\n", "'nowhere' is not a traffic-light program"),
    ],
)
def test_a_placement_files_errors_name_the_file(
    info: NetInfo, tmp_path: Path, text: str, match: str
) -> None:
    f = tmp_path / "my-units.yaml"
    f.write_text(text)
    with pytest.raises(ConfigError, match=rf"^{re.escape(str(f))}: .*{re.escape(match)}"):
        placed_units(info, f)


def test_a_unit_of_ones_own_may_stand_just_beyond_the_nets_edge(
    info: NetInfo, tmp_path: Path
) -> None:
    x1 = info.bounds_m[2]
    f = tmp_path / "edge.yaml"
    f.write_text(f"units:\n  - {{id: edge, x_m: {x1 + 40.0}, y_m: 0, boresight_deg: 270}}\n")
    assert "edge" in [u.id for u in placed_units(info, f)]


def test_the_users_files_are_judged_before_the_demand_is_made(
    grid_net: Path, tmp_path: Path
) -> None:
    from rfsas_hw.city.run import CityRunConfig, prepare_district

    poly = tmp_path / "bad.poly.xml"
    poly.write_text('<additional><poly id="b" type="building" shape="1,2 3"/></additional>')
    cfg = CityRunConfig(net=grid_net, polygons=poly)
    with pytest.raises(ConfigError, match="bad shape"):
        prepare_district(cfg, tmp_path / "out")
    assert not (tmp_path / "out" / "demand").exists()


def test_a_net_without_traffic_lights_asks_for_units_of_ones_own(info: NetInfo) -> None:
    from dataclasses import replace

    plain = replace(info, junctions=tuple(replace(j, tls=()) for j in info.junctions))
    with pytest.raises(ConfigError, match="has no traffic light to place them at; list units"):
        place_units(plain)
