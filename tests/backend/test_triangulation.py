"""Triangulation: Monte Carlo against the Cramér–Rao bound, flags for bad geometry."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest
from scipy.special import chdtri

from rfsas_hw.angles import math_rad_to_compass
from rfsas_hw.backend.triangulation import (
    FixStatus,
    TriangulationOptions,
    bearing_crb,
    triangulate,
    triangulate_batch,
)
from rfsas_hw.errors import BackendError

Array = npt.NDArray[np.float64]
CHI2_2_999 = float(chdtri(2, 1e-3))  # 13.8: NEES a covered 2-D error exceeds 0.1 % of the time


def true_azimuths(stations: Array, target: Array) -> Array:
    d = target - stations
    return np.asarray(math_rad_to_compass(np.arctan2(d[:, 1], d[:, 0])))


def monte_carlo(
    stations: Array, target: Array, sigmas: Array, n: int, seed: int, **options: float
) -> tuple[Array, Array, npt.NDArray[np.bool_]]:
    """n noisy fixes of one geometry: errors (n, 2), NEES (n,) (NaN if flagged), ok mask."""
    rng = np.random.default_rng(seed)
    az = true_azimuths(stations, target)[None] + rng.normal(0.0, 1.0, (n, len(stations))) * sigmas
    res = triangulate_batch(
        np.broadcast_to(stations, (n, *stations.shape)),
        az,
        np.broadcast_to(sigmas, az.shape),
        TriangulationOptions(**options),  # type: ignore[arg-type]
    )
    err = res.position - target
    ok = res.ok
    nees = np.full(n, np.nan)
    nees[ok] = np.einsum("bi,bij,bj->b", err[ok], np.linalg.inv(res.covariance[ok]), err[ok])
    return err, nees, ok


def test_good_geometry_reaches_the_crb_and_its_covariance_is_consistent() -> None:
    stations = np.array([[-50.0, -50.0], [50.0, -50.0], [0.0, 60.0]])
    target = np.array([5.0, 3.0])
    sigmas = np.array([1.0, 1.5, 1.0])
    n = 20_000
    err, nees, ok = monte_carlo(stations, target, sigmas, n, seed=6)
    assert ok.mean() > 0.999
    crb_rms = np.sqrt(np.trace(bearing_crb(stations, target, sigmas)))
    rms = np.sqrt(np.mean(np.sum(err[ok] ** 2, axis=1)))
    assert abs(rms / crb_rms - 1) < 0.05, (rms, crb_rms)
    # mean NEES of m fixes is χ²(2m)/m; two-sided 99 % bounds
    m = int(ok.sum())
    lo, hi = chdtri(2 * m, 0.995) / m, chdtri(2 * m, 0.005) / m
    assert lo < np.mean(nees[ok]) < hi, (lo, np.mean(nees[ok]), hi)


def test_two_stations_at_right_angles_reach_the_crb() -> None:
    stations = np.array([[-40.0, 0.0], [0.0, -40.0]])
    target = np.array([0.0, 0.0])
    sigmas = np.array([1.0, 2.0])
    err, nees, ok = monte_carlo(stations, target, sigmas, 10_000, seed=7)
    assert ok.all()
    crb = bearing_crb(stations, target, sigmas)
    # anisotropic bound: check each axis, not only the trace
    np.testing.assert_allclose(np.cov(err.T), crb, rtol=0.06, atol=0.03 * crb.max())
    m = len(nees)
    assert chdtri(2 * m, 0.995) / m < nees.mean() < chdtri(2 * m, 0.005) / m


def test_wrap_safe_across_north_and_across_west() -> None:
    # emitter due west of two stations (math angle ±π) and due north of a third (compass 0/360)
    stations = np.array([[60.0, 20.0], [60.0, -20.0], [-100.0, -80.0]])
    target = np.array([-100.0, 0.0])
    sigmas = np.array([2.0, 2.0, 2.0])
    az = true_azimuths(stations, target)
    assert abs(az[2]) < 1e-9 or abs(az[2] - 360) < 1e-9
    err, nees, ok = monte_carlo(stations, target, sigmas, 10_000, seed=8)
    assert ok.mean() > 0.999
    m = int(ok.sum())
    assert chdtri(2 * m, 0.995) / m < nees[ok].mean() < chdtri(2 * m, 0.005) / m
    crb_rms = np.sqrt(np.trace(bearing_crb(stations, target, sigmas)))
    assert abs(np.sqrt(np.mean(np.sum(err[ok] ** 2, 1))) / crb_rms - 1) < 0.05
    # the same bearings written as 359.9° or -0.1° give the same fix
    a = triangulate(stations, [az[0], az[1], 359.9], sigmas)
    b = triangulate(stations, [az[0] - 360, az[1] + 360, -0.1], sigmas)
    np.testing.assert_allclose(a.position, b.position, atol=1e-9)


@pytest.mark.parametrize(
    ("baseline", "rng_m", "sigma", "offset"),
    [
        (10.0, 100.0, 1.0, 0.0),  # nearly parallel lines of bearing
        (10.0, 50.0, 1.0, 0.5),
        (20.0, 200.0, 0.5, 0.5),
        (80.0, 3.0, 2.0, 0.0),  # emitter almost on the baseline between the stations
        (5.0, 20.0, 1.0, 0.5),  # near the acceptance limit: a few accepted
        (10.0, 20.0, 2.0, 0.0),  # about half accepted
        (20.0, 50.0, 1.0, 0.5),  # nearly all accepted
    ],
)
def test_poor_geometry_is_never_a_silent_wrong_fix(
    baseline: float, rng_m: float, sigma: float, offset: float
) -> None:
    stations = np.array([[-baseline / 2, 0.0], [baseline / 2, 0.0]])
    target = np.array([offset * rng_m, rng_m])
    n = 10_000
    _, nees, ok = monte_carlo(stations, target, np.array([sigma, sigma]), n, seed=9)
    # a fix is wrong and silent when it is accepted and its covariance misses the
    # error at 99.9 %; a calibrated covariance does that 0.1 % of the time
    silent = np.sum(ok & (nees > CHI2_2_999)) / n
    assert silent < 0.005, (silent, ok.mean())


def test_flagged_geometry_gets_the_right_status_and_reason() -> None:
    two = [[0.0, 0.0], [10.0, 0.0]]
    parallel = triangulate(two, [0.0, 0.0], [1.0, 1.0])
    assert parallel.status is FixStatus.ILL_CONDITIONED and not parallel.ok
    assert "parallel" in parallel.reason
    facing = triangulate(two, [90.0, 270.0], [1.0, 1.0])  # same line, looking at each other
    assert facing.status is FixStatus.ILL_CONDITIONED
    near = triangulate(two, [89.0, 271.0], [1.0, 1.0])
    assert near.status is FixStatus.ILL_CONDITIONED and "condition" in near.reason
    diverging = triangulate(two, [350.0, 10.0], [1.0, 1.0])
    assert diverging.status is FixStatus.BEHIND_SENSOR and "behind" in diverging.reason
    np.testing.assert_allclose(diverging.position, [5.0, -5.0 / np.tan(np.deg2rad(10))], rtol=1e-9)
    one = triangulate([[0.0, 0.0]], [45.0], [1.0])
    assert one.status is FixStatus.TOO_FEW_BEARINGS and "too few" in one.reason
    three = [[0.0, 0.0], [10.0, 0.0], [5.0, -50.0]]
    good = triangulate(three, [45.0, 315.0, 0.0], [1.0, 1.0, 1.0])
    assert good.ok and good.reason.startswith("ok")
    np.testing.assert_allclose(good.position, [5.0, 5.0], atol=1e-6)
    bad = triangulate(three, [45.0, 315.0, 10.0], [1.0, 1.0, 1.0])
    assert bad.status is FixStatus.INCONSISTENT and "χ²" in bad.reason


def test_closed_form_covariance_uses_lambda_for_sigma_y() -> None:
    # an asymmetric geometry where μ ≠ λ; compare with a numerical Jacobian
    stations = np.array([[-30.0, -5.0], [40.0, -20.0], [10.0, 70.0]])
    target = np.array([3.0, 7.0])
    sigmas = np.array([0.7, 1.3, 2.1])
    crb = bearing_crb(stations, target, sigmas)
    eps = 1e-6

    def az_rad(p: Array) -> Array:
        d = p - stations
        return np.asarray(np.arctan2(d[:, 1], d[:, 0]), np.float64)

    G = np.stack(
        [(az_rad(target + e) - az_rad(target - e)) / (2 * eps) for e in np.eye(2) * eps], axis=1
    )
    W = np.diag(1 / np.deg2rad(sigmas) ** 2)
    np.testing.assert_allclose(crb, np.linalg.inv(G.T @ W @ G), rtol=1e-6)
    assert abs(crb[0, 0] - crb[1, 1]) > 0.1 * crb.max()
    fix = triangulate(stations, true_azimuths(stations, target), sigmas)
    np.testing.assert_allclose(fix.covariance, crb, rtol=1e-6)


def test_noise_free_bearings_give_the_exact_point_in_random_geometries() -> None:
    rng = np.random.default_rng(11)
    B, N = 500, 4
    stations = rng.uniform(-100, 100, (B, N, 2))
    targets = rng.uniform(-30, 30, (B, 2))
    d = targets[:, None, :] - stations
    az = math_rad_to_compass(np.arctan2(d[..., 1], d[..., 0]))
    res = triangulate_batch(stations, az, np.full((B, N), 1.0))
    good = res.condition < 1e3
    assert good.mean() > 0.9
    np.testing.assert_allclose(res.position[good], targets[good], atol=1e-6)


def test_a_fix_alone_is_its_row_of_a_batch() -> None:
    """Rows are independent: a fix gives the same result alone as among 400 others.

    Random geometries give every status: ok, parallel, behind, inconsistent, too few.
    """
    rng = np.random.default_rng(12)
    B = 400
    stations = rng.uniform(-60, 60, (B, 4, 2))
    targets = rng.uniform(-40, 40, (B, 2))
    d = targets[:, None, :] - stations
    az = math_rad_to_compass(np.arctan2(d[..., 1], d[..., 0])) + rng.normal(0, 2, (B, 4))
    az[::7] = rng.uniform(0, 360, (len(az[::7]), 4))  # unrelated bearings
    sig = rng.uniform(0.5, 3, (B, 4))
    az[::3, 3] = np.nan
    az[1::5, 2:] = np.nan
    az[2::11, 1:] = np.nan
    options = TriangulationOptions(max_iterations=6)
    batch = triangulate_batch(stations, az, sig, options)
    seen = set()
    for i in range(B):
        keep = np.isfinite(az[i])
        single = triangulate(stations[i][keep], az[i][keep], sig[i][keep], options)
        seen.add(single.status)
        assert single.status == batch.status[i], i
        assert single.n_bearings == keep.sum() and single.iterations == batch.iterations[i]
        np.testing.assert_allclose(single.position, batch.position[i], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(single.covariance, batch.covariance[i], rtol=1e-12)
        np.testing.assert_allclose(
            [single.gdop, single.condition], [batch.gdop[i], batch.condition[i]], rtol=1e-12
        )
        assert single.reason == batch.reason(i)
    assert seen >= set(FixStatus) - {FixStatus.NOT_CONVERGED}


def test_iteration_cap_is_reported() -> None:
    stations = np.array([[-50.0, -50.0], [50.0, -50.0], [0.0, 60.0]])
    az = true_azimuths(stations, np.array([5.0, 3.0])) + np.array([1.0, -1.5, 0.8])
    capped = triangulate(
        stations, az, [1.0, 1.0, 1.0], TriangulationOptions(max_iterations=1, tolerance_m=1e-9)
    )
    assert capped.status is FixStatus.NOT_CONVERGED and "not converged" in capped.reason
    free = triangulate(stations, az, [1.0, 1.0, 1.0], TriangulationOptions(tolerance_m=1e-9))
    assert free.ok and free.iterations > 1
    np.testing.assert_allclose(free.position, capped.position, atol=1e-3)


def test_bad_inputs_raise_clear_errors() -> None:
    with pytest.raises(BackendError, match="sigma of bearing 1"):
        triangulate([[0, 0], [1, 0]], [0, 10], [1, 0])
    with pytest.raises(BackendError, match="shape"):
        triangulate([[0, 0, 0], [1, 0, 0]], [0, 10], [1, 1])
    with pytest.raises(BackendError, match="must match"):
        triangulate([[0, 0], [1, 0]], [0, 10, 20], [1, 1, 1])
    with pytest.raises(BackendError, match="max_range_fraction"):
        TriangulationOptions(max_range_fraction=0)


def test_no_bound_for_an_emitter_on_a_station() -> None:
    """A bearing from a station to itself has no direction: the bound is infinite there,
    finite one metre away."""
    stations = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
    assert np.isinf(bearing_crb(stations, [0.0, 0.0], [1.0, 1.0, 1.0])).all()
    near = bearing_crb(stations, [0.6, 0.8], [1.0, 1.0, 1.0])
    assert np.isfinite(near).all() and near[0, 0] > 0 and near[1, 1] > 0
