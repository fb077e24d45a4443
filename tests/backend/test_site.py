"""The site section of the backend settings: origin, sensor poses in either form, map, tiles."""

from __future__ import annotations

from pathlib import Path

import pytest

from rfsas_hw.backend.service import load_backend_config
from rfsas_hw.backend.site import parse_origin, pose_from_mapping, site_from_mapping
from rfsas_hw.errors import ConfigError
from rfsas_hw.geo import SiteOrigin

ORIGIN = SiteOrigin(52.2053, 0.1218, 12.0)


def test_geodetic_and_local_poses_agree_within_a_centimetre() -> None:
    lat, lon, _ = ORIGIN.to_geodetic(-9.0, 9.0)
    geo = pose_from_mapping(
        {"lat_deg": float(lat), "lon_deg": float(lon), "heading_deg": 500.0}, ORIGIN, "s"
    )
    assert abs(geo.x_m + 9.0) < 0.01 and abs(geo.y_m - 9.0) < 0.01
    assert geo.heading_deg == pytest.approx(140.0)
    local = pose_from_mapping({"x_m": -9, "y_m": 9, "heading_deg": 140}, None, "s")
    assert (local.x_m, local.y_m, local.heading_deg) == (-9.0, 9.0, 140.0)


@pytest.mark.parametrize(
    ("data", "origin", "message"),
    [
        ({"x_m": 1, "lat_deg": 2, "heading_deg": 0}, ORIGIN, "not both or neither"),
        ({"heading_deg": 0}, ORIGIN, "not both or neither"),
        ({"lat_deg": 52, "lon_deg": 0, "heading_deg": 0}, None, "needs the site origin"),
        ({"x_m": 1, "y_m": "a", "heading_deg": 0}, None, r"s\.y_m: expected a finite number"),
        ({"x_m": 1, "y_m": 2}, None, "missing key heading_deg"),
        ({"lat_deg": 95, "lon_deg": 0, "heading_deg": 0}, ORIGIN, "not a latitude"),
    ],
)
def test_bad_pose_names_the_place(data: dict[str, object], origin: SiteOrigin | None,
                                  message: str) -> None:  # fmt: skip
    with pytest.raises(ConfigError, match=message):
        pose_from_mapping(data, origin, "s")


def test_site_section_of_the_backend_settings(tmp_path: Path) -> None:
    lat, lon, _ = ORIGIN.to_geodetic(25.0, -20.0)
    cfg = tmp_path / "backend.yaml"
    cfg.write_text(
        "step_s: 0.2\n"
        "site:\n"
        "  origin: {lat_deg: 52.2053, lon_deg: 0.1218, height_m: 12}\n"
        "  map: site.geojson\n"
        "  tiles: https://tiles.example/{z}/{x}/{y}.png\n"
        "  sensors:\n"
        "    rsu-a: {x_m: -30, y_m: 10, heading_deg: 90, fov_deg: 60}\n"
        f"    rsu-b: {{lat_deg: {float(lat)!r}, lon_deg: {float(lon)!r}, heading_deg: 0}}\n"
    )
    config = load_backend_config(cfg)
    site = config.site
    assert config.step_s == 0.2 and site.origin == ORIGIN
    assert site.map == tmp_path / "site.geojson"
    a, b = site.sensor("rsu-a"), site.sensor("rsu-b")
    assert a is not None and a.fov_deg == 60 and a.pose.x_m == -30
    assert b is not None and b.fov_deg == 90
    assert abs(b.pose.x_m - 25.0) < 0.01 and abs(b.pose.y_m + 20.0) < 0.01


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"origin": {"lat_deg": 0}}, r"site\.origin: missing key lon_deg"),
        ({"sensors": {"x": {"x_m": 0, "y_m": 0, "heading_deg": 0, "fov": 3}}}, "unknown key"),
        ({"sensors": {"x": {"x_m": 0, "y_m": 0, "heading_deg": 0, "fov_deg": 0}}}, "fov_deg"),
        ({"tiles": "https://t.example/{z}/{x}.png"}, r"\{y\}"),
        ({"tiles": "file:///{z}/{x}/{y}.png"}, "http"),
        ({"zoom": 3}, "unknown key"),
    ],
)
def test_bad_site_names_the_key(data: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        site_from_mapping(data, "backend.yaml: site")


def test_origin_option_text() -> None:
    assert parse_origin("52.2053,0.1218,12") == ORIGIN
    assert parse_origin("52.2053,0.1218").height_m == 0.0
    for bad in ("52.2", "a,b", "95,0"):
        with pytest.raises(ConfigError, match="origin"):
            parse_origin(bad)


def test_sensor_pose_option_on_the_globe() -> None:
    from rfsas_hw.cli.sensoropts import parse_pose

    lat, lon, _ = ORIGIN.to_geodetic(-9.0, 9.0)
    pose = parse_pose(f"geo:{float(lat)!r},{float(lon)!r},140", "52.2053,0.1218,12")
    assert abs(pose.x_m + 9.0) < 0.01 and abs(pose.y_m - 9.0) < 0.01
    assert pose.heading_deg == 140.0
    assert parse_pose("-9,9,500") == parse_pose("-9,9,140")
    with pytest.raises(ConfigError, match="needs --origin"):
        parse_pose("geo:52.2,0.12,0")
    with pytest.raises(ConfigError, match="expected geo:LAT_DEG"):
        parse_pose("geo:52.2,0.12", "52.2053,0.1218")
