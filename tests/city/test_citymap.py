"""The district map: PNG and GeoJSON of units, crossings, conflicts and nuisance BRAKEs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("sumo", reason="needs the city extra: pip install 'rfsas-hw[city]'")
pytest.importorskip("sumolib", reason="needs the city extra: pip install 'rfsas-hw[city]'")

from rfsas_hw.city.citymap import write_map
from rfsas_hw.city.latency import LatencyParts
from rfsas_hw.city.net import read_net
from rfsas_hw.city.placement import place_units
from rfsas_hw.city.scoring import Actors, CityScorer

pytest.importorskip("matplotlib", reason="needs the plot extra: pip install 'rfsas-hw[plot]'")


def test_map_holds_every_kind_and_no_emitter_id(grid_net: Path, tmp_path: Path) -> None:
    info = read_net(grid_net)
    units = place_units(info)
    crossing = info.crossings[0]
    scorer = CityScorer(info.crossings)
    kx, ky = crossing.kerb_a
    cars = Actors.of(
        ["car1", "car2"], ["vehicle"] * 2, [0.0, 60.0], [0.0, 0.0], 10.0, 0.0, 4.5, 1.8
    )
    peds = Actors.of(
        ["ped1", "ped2"], ["pedestrian"] * 2, [0.0, kx], [12.0, ky], 0.0, 0.0, 0.5, 0.5
    )
    scorer.fix(0.0, "a1b2c3d4e5f60718", "ped2", kx + 1.0, ky, 2.0)
    scorer.step(0.0, cars, peds)
    scorer.advisory(
        0.0, "car2", "brake", LatencyParts(0.01, 0.005, 0.005)
    )  # no VRU ahead of car2: a nuisance
    png, gj = tmp_path / "city.png", tmp_path / "city.geojson"
    assert write_map(scorer, units, info, png, gj) == [gj, png]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = gj.read_text()
    doc = json.loads(text)
    kinds = [f["properties"]["kind"] for f in doc["features"]]
    assert kinds.count("unit") == len(units)
    assert kinds.count("conflict") == 1 and kinds.count("nuisance_brake") == 1
    (reached,) = [f for f in doc["features"] if f["properties"]["kind"] == "crossing"]
    assert reached["properties"]["covered"] == 1
    lon, lat = reached["geometry"]["coordinates"]
    assert abs(lat - info.origin.lat_deg) < 0.01 and abs(lon - info.origin.lon_deg) < 0.01
    assert "a1b2c3d4e5f60718" not in text
