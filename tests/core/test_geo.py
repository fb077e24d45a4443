"""Site origin: local metres ↔ WGS-84 (pymap3d, and a closed form checked against it)."""

from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest

from rfsas_hw.errors import ConfigError
from rfsas_hw.geo import SiteOrigin, site_origin_from_mapping


def test_round_trip_within_a_millimetre_over_a_site() -> None:
    origin = SiteOrigin(52.2053, 0.1218, 12.0)
    rng = np.random.default_rng(1)
    e = rng.uniform(-2000, 2000, 500)
    n = rng.uniform(-2000, 2000, 500)
    lat, lon, h = origin.to_geodetic(e, n)
    e2, n2, u2 = origin.to_local(lat, lon, h)
    assert np.max(np.abs(e2 - e)) < 1e-3
    assert np.max(np.abs(n2 - n)) < 1e-3
    assert np.max(np.abs(u2)) < 1e-3


def test_north_is_north_and_east_is_east() -> None:
    origin = SiteOrigin(45.0, 7.0)
    lat, lon, _ = origin.to_geodetic(0.0, 1000.0)
    # one minute of latitude ≈ 1852 m; 1000 m north is ≈ 0.009°
    assert float(lat) == pytest.approx(45.0 + 1000.0 / 111_132.0, abs=2e-5)
    assert float(lon) == pytest.approx(7.0, abs=1e-9)
    lat, lon, _ = origin.to_geodetic(1000.0, 0.0)
    expected = 1000.0 / (111_320.0 * math.cos(math.radians(45.0)))
    assert float(lon) - 7.0 == pytest.approx(expected, rel=5e-3)
    assert float(lat) == pytest.approx(45.0, abs=1e-4)


def test_lat_lon_without_height_lands_on_the_site_plane() -> None:
    origin = SiteOrigin(-33.9, 151.2, 40.0)
    lat, lon, _ = origin.to_geodetic(30.0, -20.0)
    e, n, u = origin.to_local(lat, lon)
    assert float(e) == pytest.approx(30.0, abs=1e-3)
    assert float(n) == pytest.approx(-20.0, abs=1e-3)
    assert abs(float(u)) < 0.01


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"lat_deg": 91, "lon_deg": 0}, "lat_deg"),
        ({"lat_deg": 0, "lon_deg": "east"}, "lon_deg: expected a number"),
        ({"lat_deg": 0}, "missing key lon_deg"),
        ({"lat_deg": 0, "lon_deg": 0, "alt": 3}, "unknown key(s) alt"),
        ({"lat_deg": float("nan"), "lon_deg": 0}, "lat_deg"),
        ([1, 2], "expected a mapping"),
    ],
)
def test_bad_origin_names_the_key(data: object, message: str) -> None:
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)")):
        site_origin_from_mapping(data, "site.yaml: origin")  # type: ignore[arg-type]


@pytest.mark.parametrize("lat0", [-89.9, -33.9, 0.0, 48.137, 78.2, 89.99])
@pytest.mark.parametrize("lon0", [-179.9, 0.0, 11.575, 179.99])
def test_closed_form_local_to_geodetic_agrees_with_pymap3d(lat0: float, lon0: float) -> None:
    """The closed-form conversion matches pymap3d's iterative one within 1e-9° and 0.1 mm,
    ±50 km around origins from pole to pole and across the antimeridian."""
    rng = np.random.default_rng(abs(int(lat0 * 100 + lon0)))
    origin = SiteOrigin(lat0, lon0, float(rng.uniform(-100.0, 3000.0)))
    e, n, u = (
        rng.uniform(-50e3, 50e3, 300),
        rng.uniform(-50e3, 50e3, 300),
        rng.uniform(-200, 2e3, 300),
    )
    lat, lon, h = origin.to_geodetic(e, n, u)
    ref_lat, ref_lon, ref_h = pymap3d.enu2geodetic(e, n, u, lat0, lon0, origin.height_m)
    assert np.abs(lat - ref_lat).max() < 1e-9
    assert np.abs((lon - ref_lon + 180.0) % 360.0 - 180.0).max() < 1e-9
    assert np.abs(h - ref_h).max() < 1e-4
