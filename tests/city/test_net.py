"""The district net: found in the wheel, read into the rfsas frame."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("sumo", reason="needs the city extra: pip install 'rfsas-hw[city]'")
pytest.importorskip("sumolib", reason="needs the city extra: pip install 'rfsas-hw[city]'")

from rfsas_hw.city.net import DEFAULT_ORIGIN, district_net, read_net, sumo_env
from rfsas_hw.errors import ConfigError
from rfsas_hw.geo import SiteOrigin


def test_grid_net_is_read_in_a_frame_centred_on_its_boundary(grid_net: Path) -> None:
    info = read_net(grid_net)
    assert not info.georeferenced
    assert info.origin == DEFAULT_ORIGIN
    # a 3 x 3 grid 120 m apart with 60 m stubs: 360 m square, centred
    assert info.bounds_m == pytest.approx((-180.0, -180.0, 180.0, 180.0))
    assert len(info.tls_junctions) == 9
    centres = sorted((round(j.x_m), round(j.y_m)) for j in info.tls_junctions)
    assert centres == [(x, y) for x in (-120, 0, 120) for y in (-120, 0, 120)]
    # a crossing over every arm of every junction: 4 arms x 9 junctions
    assert len(info.crossings) == 36
    assert all(c.signalised for c in info.crossings)
    assert all(5.0 < c.length_m < 20.0 for c in info.crossings)
    assert any(r.pedestrian_only for r in info.roads)
    assert all(r.cars != r.pedestrian_only for r in info.roads)  # a road and its sidewalks


def test_a_net_without_projection_is_placed_at_the_given_origin(grid_net: Path) -> None:
    here = SiteOrigin(48.1, 11.5)
    info = read_net(grid_net, origin=here)
    assert info.origin == here
    e, n = info.to_frame([180.0, 300.0], [180.0, 60.0])
    assert np.allclose(e, [0.0, 120.0]) and np.allclose(n, [0.0, -120.0])
    x, y = info.to_net(e, n)
    assert np.allclose(x, [180.0, 300.0]) and np.allclose(y, [180.0, 60.0])


def test_missing_and_non_net_files_fail_with_the_file_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such net file"):
        read_net(tmp_path / "absent.net.xml")
    bad = tmp_path / "bad.net.xml"
    bad.write_text('<?xml version="1.0"?>\n<!DOCTYPE net [<!ENTITY a "x">]>\n<net/>\n')
    with pytest.raises(ConfigError, match="document type"):
        read_net(bad)
    poly = tmp_path / "buildings.poly.xml"  # well-formed SUMO XML, but not a net
    poly.write_text('<additional><poly id="b" type="building" shape="0,0 9,0 9,9"/></additional>')
    with pytest.raises(ConfigError, match=r"buildings\.poly\.xml: not a SUMO net"):
        read_net(poly)


def test_the_environment_points_proj_at_the_wheel() -> None:
    env = sumo_env()
    assert Path(env["PROJ_LIB"]).is_dir()
    assert (Path(env["PROJ_LIB"]) / "proj.db").is_file()
    assert env["PROJ_DATA"] == env["PROJ_LIB"]


@pytest.fixture(scope="module")
def district() -> object:
    try:
        path = district_net()
    except ConfigError as err:
        pytest.skip(str(err))
    return read_net(path)


def test_district_frame_is_enu_at_its_centre(district: object) -> None:
    """The fitted frame agrees with the net's own projection: a point 1 km from the
    centre lands where SiteOrigin.to_local puts its projected latitude/longitude."""
    import sumolib

    from rfsas_hw.city.net import NetInfo

    assert isinstance(district, NetInfo)
    info = district
    assert info.georeferenced
    # Adlershof lies west of UTM zone 33's central meridian (15 E): grid north is
    # turned from true north by the meridian convergence, (lon - 15) * sin(lat) ~ -1.2 deg
    expected = (info.origin.lon_deg - 15.0) * math.sin(math.radians(info.origin.lat_deg))
    assert info.rotation_deg == pytest.approx(-expected, abs=0.05)
    assert info.frame_residual_m < 0.05
    net = sumolib.net.readNet(str(info.path))
    cx, cy = info.net_centre
    lon, lat = net.convertXY2LonLat(cx + 700.0, cy - 700.0)
    e, n, _ = info.origin.to_local(lat, lon)
    fe, fn = info.to_frame(cx + 700.0, cy - 700.0)
    assert math.hypot(float(fe) - float(e), float(fn) - float(n)) < 0.05
    # the district as the issue describes it
    assert len(info.crossings) == 503
    assert len({t for j in info.tls_junctions for t in j.tls}) == 21
