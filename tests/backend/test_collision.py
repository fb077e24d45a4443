"""Probability of collision: the exact Owen's T integral against Lambert's Monte Carlo."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from scipy.special import ndtr

from rfsas_hw.backend.collision import (
    THREAT_SIZES,
    VEHICLE_SIZE,
    collision_probability,
    collision_probability_batch,
    collision_probability_mc,
    heading_covariance,
    minkowski_octagon,
    threat_box,
)
from rfsas_hw.errors import BackendError

Array = npt.NDArray[np.float64]


def random_case(rng: np.random.Generator) -> dict[str, object]:
    """A vehicle and a threat near each other, random sizes, headings and covariances."""

    def cov() -> Array:
        a = rng.normal(size=(2, 2))
        return np.asarray(a @ a.T * rng.uniform(0.05, 4.0), np.float64)

    return {
        "vehicle_xy": rng.uniform(-2, 2, 2),
        "vehicle_heading_deg": float(rng.uniform(0, 360)),
        "vehicle_cov": cov(),
        "vehicle_size": rng.uniform(0.3, 5.0, 2),
        "threat_xy": rng.uniform(-4, 4, 2),
        "threat_heading_deg": float(rng.uniform(0, 360)),
        "threat_cov": cov(),
        "threat_size": rng.uniform(0.3, 5.0, 2),
    }


def test_exact_matches_a_million_sample_monte_carlo_on_random_cases() -> None:
    rng = np.random.default_rng(20)
    results = []
    for i in range(20):
        case = random_case(rng)
        exact = collision_probability(**case)  # type: ignore[arg-type]
        # at least 1e6 samples, more where p(1−p) is large, so that 1e-3 is ≥ 4 standard errors
        n = max(1_000_000, math.ceil(16 * exact * (1 - exact) / 1e-6))
        mc = collision_probability_mc(**case, n=n, seed=1000 + i)  # type: ignore[arg-type]
        results.append((exact, mc.p, mc.stderr))
        assert abs(exact - mc.p) <= 1e-3, (i, exact, mc.p)
        assert abs(exact - mc.p) <= 4 * max(mc.stderr, 1 / n), (i, exact, mc.p, mc.stderr)
    ps = np.array([r[0] for r in results])
    # the cases span the range, not only near-certain or near-impossible collisions
    assert (ps > 0.05).sum() >= 8 and (ps < 0.6).sum() >= 8


def test_axis_aligned_boxes_with_isotropic_error_match_the_product_of_normal_cdfs() -> None:
    # both boxes heading north: the Minkowski sum is a (Lv+Lt) × (Wv+Wt) rectangle,
    # and with Σ = σ²I the mass factorises into two one-dimensional normal intervals
    sigma_v, sigma_t = 1.2, 0.7
    s = math.hypot(sigma_v, sigma_t)
    mu = np.array([0.8, 2.1])
    half_x = (1.8 + 0.6) / 2  # widths across a northward heading lie along x
    half_y = (4.5 + 1.8) / 2
    expected = (ndtr((half_x - mu[0]) / s) - ndtr((-half_x - mu[0]) / s)) * (
        ndtr((half_y - mu[1]) / s) - ndtr((-half_y - mu[1]) / s)
    )
    got = collision_probability(
        [0, 0], 0.0, np.eye(2) * sigma_v**2, (4.5, 1.8), mu, 0.0, np.eye(2) * sigma_t**2, "cyclist"
    )
    assert got == pytest.approx(expected, abs=1e-12)
    # rotating the whole scene changes nothing
    rot = 37.0
    a = math.radians(-rot)
    R = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    got_rot = collision_probability(
        [0, 0],
        rot,
        np.eye(2) * sigma_v**2,
        (4.5, 1.8),
        R @ mu,
        rot,
        np.eye(2) * sigma_t**2,
        "cyclist",
    )
    assert got_rot == pytest.approx(expected, abs=1e-12)


def test_one_call_is_its_row_of_the_batch() -> None:
    rng = np.random.default_rng(21)
    cases = [random_case(rng) for _ in range(200)]
    batch = collision_probability_batch(
        np.array([c["vehicle_xy"] for c in cases]),
        np.array([c["vehicle_heading_deg"] for c in cases]),
        np.array([c["vehicle_cov"] for c in cases]),
        np.array([c["vehicle_size"] for c in cases]),
        np.array([c["threat_xy"] for c in cases]),
        np.array([c["threat_heading_deg"] for c in cases]),
        np.array([c["threat_cov"] for c in cases]),
        np.array([c["threat_size"] for c in cases]),
    )
    single = np.array([collision_probability(**c) for c in cases])  # type: ignore[arg-type]
    np.testing.assert_allclose(single, batch, atol=1e-12)


def test_heading_convention_and_point_masses() -> None:
    zero = np.zeros((2, 2))
    # Point masses inside the octagon give 1 up to rounding: cos 90° is ~6e-17, not 0,
    # and how that rounds differs between numpy's vectorised sin/cos builds.
    one = pytest.approx(1.0, abs=1e-12)
    # heading 90° (east): the 4.5 m length lies along x
    assert collision_probability([0, 0], 90.0, zero, None, [2.4, 0], 0, zero, "pedestrian") == one
    assert collision_probability([0, 0], 90.0, zero, None, [0, 2.4], 0, zero, "pedestrian") < 1e-12
    assert collision_probability([0, 0], 0.0, zero, None, [0, 2.4], 0, zero, "pedestrian") == one
    far = collision_probability([0, 0], 0.0, None, None, [60, 0], 0, np.eye(2), "vehicle")
    assert 0.0 <= far < 1e-12


def test_minkowski_octagon_has_the_support_function_of_the_sum() -> None:
    rng = np.random.default_rng(22)
    B = 50
    sa, sb = rng.uniform(0, 5, (B, 2)), rng.uniform(0, 5, (B, 2))
    ha, hb = rng.uniform(0, 360, B), rng.uniform(-360, 720, B)
    sa[0] = 0.0  # a point box
    hb[1] = ha[1]  # parallel boxes: collinear edges
    poly = minkowski_octagon(sa, ha, sb, hb)
    edges = np.roll(poly, -1, axis=1) - poly
    cross = (
        edges[..., 0] * np.roll(edges, -1, axis=1)[..., 1]
        - edges[..., 1] * np.roll(edges, -1, axis=1)[..., 0]
    )
    assert np.all(cross >= -1e-9)  # convex, counter-clockwise
    for theta in np.linspace(0, 2 * np.pi, 13):
        k = np.array([math.cos(theta), math.sin(theta)])

        def support(size: Array, heading: Array, k: Array = k) -> Array:
            a = np.deg2rad(90 - heading)
            u = np.stack([np.cos(a), np.sin(a)], -1)
            n = np.stack([-u[:, 1], u[:, 0]], -1)
            return np.asarray(size[:, 0] / 2 * np.abs(u @ k) + size[:, 1] / 2 * np.abs(n @ k))

        np.testing.assert_allclose(
            (poly @ k).max(axis=1), support(sa, ha) + support(sb, hb), atol=1e-12
        )


def test_default_vehicle_covariance_and_threat_kinds() -> None:
    np.testing.assert_allclose(heading_covariance(0.0), np.diag([1.0, 9.0]), atol=1e-12)
    np.testing.assert_allclose(heading_covariance(90.0), np.diag([9.0, 1.0]), atol=1e-12)
    c45 = heading_covariance(45.0)
    assert c45[0, 1] == pytest.approx(4.0)  # (9 − 1)/2, positive: along-track is north-east
    assert VEHICLE_SIZE == (4.5, 1.8)
    assert threat_box("pedestrian") == THREAT_SIZES["pedestrian"]
    assert threat_box((2, 1)) == (2.0, 1.0)
    # None means the defaults
    case: dict[str, Any] = {
        "threat_xy": [1.0, 3.0],
        "threat_heading_deg": 0.0,
        "threat_cov": np.eye(2),
    }
    explicit = collision_probability(
        [0, 0], 30.0, heading_covariance(30.0), (4.5, 1.8), threat_size="pedestrian", **case
    )
    default = collision_probability([0, 0], 30.0, None, None, threat_size="pedestrian", **case)
    assert default == explicit and 0.05 < default < 0.95


def test_monte_carlo_is_seeded_and_handles_heading_uncertainty() -> None:
    args = ([0, 0], 0.0, None, None, [1.5, 3.0], 90.0, np.eye(2) * 0.5, "cyclist")
    a = collision_probability_mc(*args, n=50_000, seed=5)
    b = collision_probability_mc(*args, n=50_000, seed=5)
    assert a == b
    exact = collision_probability(*args)
    jitter = collision_probability_mc(*args, n=200_000, seed=6, threat_heading_sigma_deg=1e-9)
    assert abs(jitter.p - exact) < 4 * jitter.stderr
    # a long cyclist box swinging through ±60° crosses the vehicle's path more often
    swing = collision_probability_mc(*args, n=200_000, seed=7, threat_heading_sigma_deg=60.0)
    assert swing.p > exact + 4 * swing.stderr
    assert collision_probability(*args, method="montecarlo", n=50_000, seed=5) == a.p


def test_bad_inputs_raise_clear_errors() -> None:
    good = {
        "vehicle_xy": [0, 0],
        "vehicle_heading_deg": 0.0,
        "vehicle_cov": None,
        "vehicle_size": None,
        "threat_xy": [1, 1],
        "threat_heading_deg": 0.0,
        "threat_cov": np.eye(2),
        "threat_size": "pedestrian",
    }
    with pytest.raises(BackendError, match="unknown threat kind 'dog'"):
        collision_probability(**{**good, "threat_size": "dog"})  # type: ignore[arg-type]
    with pytest.raises(BackendError, match="positive semi-definite"):
        collision_probability(**{**good, "threat_cov": [[1, 2], [2, 1]]})  # type: ignore[arg-type]
    with pytest.raises(BackendError, match="threat_xy"):
        collision_probability(**{**good, "threat_xy": [1, 2, 3]})  # type: ignore[arg-type]
    with pytest.raises(BackendError, match="vehicle_size"):
        collision_probability(**{**good, "vehicle_size": (-1, 2)})  # type: ignore[arg-type]
    with pytest.raises(BackendError, match="unknown collision method"):
        collision_probability(**good, method="guess")  # type: ignore[arg-type]
    with pytest.raises(BackendError, match="n ≥ 1"):
        collision_probability_mc(**good, n=0)  # type: ignore[arg-type]
    with pytest.raises(BackendError, match="finite"):
        collision_probability(**{**good, "threat_xy": [math.nan, 1]})  # type: ignore[arg-type]


def test_a_bad_row_of_a_batch_is_named() -> None:
    B = 4
    args: dict[str, Any] = {
        "vehicle_xy": np.zeros((B, 2)),
        "vehicle_heading_deg": 0.0,
        "vehicle_cov": np.broadcast_to(np.eye(2), (B, 2, 2)),
        "vehicle_size": VEHICLE_SIZE,
        "threat_xy": np.ones((B, 2)),
        "threat_heading_deg": np.zeros(B),
        "threat_cov": np.broadcast_to(np.eye(2), (B, 2, 2)).copy(),
        "threat_size": np.full((B, 2), 0.5),
    }
    assert collision_probability_batch(**args).shape == (B,)
    bad_cov = args["threat_cov"].copy()
    bad_cov[2, 0, 1] = 3.0
    with pytest.raises(BackendError, match=r"threat_cov must be a symmetric .* \(row 2\)"):
        collision_probability_batch(**{**args, "threat_cov": bad_cov})
    bad_cov[2, 0, 1] = math.inf
    with pytest.raises(BackendError, match=r"threat_cov must be finite \(row 2\)"):
        collision_probability_batch(**{**args, "threat_cov": bad_cov})
    bad_xy = args["threat_xy"].copy()
    bad_xy[3, 1] = math.nan
    with pytest.raises(BackendError, match=r"finite \(row 3\)"):
        collision_probability_batch(**{**args, "threat_xy": bad_xy})
    bad_size = args["threat_size"].copy()
    bad_size[1, 0] = -1.0
    with pytest.raises(BackendError, match=r"threat_size must be .* \(row 1\)"):
        collision_probability_batch(**{**args, "threat_size": bad_size})
    with pytest.raises(BackendError, match=r"vehicle_size must have shape"):
        collision_probability_batch(**{**args, "vehicle_size": np.ones(3)})
