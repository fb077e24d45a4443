"""The monopulse ratio in both modes and its gradient."""

from __future__ import annotations

import numpy as np
import pytest

from rfsas_hw.df import balance_k_d, ratio, ratio_gradient


def test_db_mode_is_the_published_formula() -> None:
    r1, r2, k = np.array([-50.0]), np.array([-60.0]), 0.9
    assert ratio(r1, r2, k, "db")[0] == pytest.approx((-50 - 0.9 * -60) / (-50 + 0.9 * -60))


def test_linear_mode_equals_the_power_ratio() -> None:
    r1, r2, k = np.array([-50.0, -70.0]), np.array([-60.0, -65.0]), 1.3
    p1, p2 = 10 ** (r1 / 10), 10 ** (r2 / 10)
    assert np.allclose(ratio(r1, r2, k, "linear"), (p1 - k * p2) / (p1 + k * p2))


def test_linear_mode_depends_only_on_the_difference_db_mode_does_not() -> None:
    lin = ratio(np.array([-40.0, -80.0]), np.array([-45.0, -85.0]), 1.0, "linear")
    db = ratio(np.array([-40.0, -80.0]), np.array([-45.0, -85.0]), 1.0, "db")
    assert lin[0] == pytest.approx(lin[1])
    assert abs(db[0]) > 1.9 * abs(db[1])  # |ψ| halves when the level doubles


@pytest.mark.parametrize("mode", ["db", "linear"])
def test_gradient_matches_finite_differences(mode: str) -> None:
    rng = np.random.default_rng(1)
    r1 = rng.uniform(-90, -30, 50)
    r2 = rng.uniform(-90, -30, 50)
    g1, g2 = ratio_gradient(r1, r2, 1.1, mode)  # type: ignore[arg-type]
    h = 1e-6
    f1 = (ratio(r1 + h, r2, 1.1, mode) - ratio(r1 - h, r2, 1.1, mode)) / (2 * h)  # type: ignore[arg-type]
    f2 = (ratio(r1, r2 + h, 1.1, mode) - ratio(r1, r2 - h, 1.1, mode)) / (2 * h)  # type: ignore[arg-type]
    assert np.allclose(g1, f1, rtol=1e-5, atol=1e-9)
    assert np.allclose(g2, f2, rtol=1e-5, atol=1e-9)


@pytest.mark.parametrize("mode", ["db", "linear"])
def test_balance_zeroes_the_ratio_at_boresight(mode: str) -> None:
    k = balance_k_d(-52.0, -53.5, mode)  # type: ignore[arg-type]
    assert ratio(np.array([-52.0]), np.array([-53.5]), k, mode)[0] == pytest.approx(0.0, abs=1e-12)  # type: ignore[arg-type]


def test_float32_inputs_stay_float32() -> None:
    r = ratio(np.array([-50.0], np.float32), np.array([-55.0], np.float32), 1.0, "linear")
    assert r.dtype == np.float32
