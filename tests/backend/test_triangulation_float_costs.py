"""The float cost functions that decide a Gauss-Newton trial give the lists' and the
arrays' sums (so trying a step costs no lists and no numpy calls).

Tolerances, not bits: numpy's ``arctan2`` may differ from :func:`math.atan2` in the last
bit (its AVX-512 kernel does), which moves a residual ``r`` by about one ulp of π; a
cost ``Σ w·r²`` then moves by at most ``Σ 2·w·|r|·δr ≤ 2π·δr·Σ w``.
"""

from __future__ import annotations

import numpy as np
import pytest

from rfsas_hw.backend import triangulation as tri


def _problems(seed: int, count: int = 400):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    for _ in range(count):
        n = int(rng.integers(2, 9))
        scale = float(10.0 ** rng.uniform(-2, 4))
        xs = (rng.uniform(-1, 1, n) * scale).tolist()
        ys = (rng.uniform(-1, 1, n) * scale).tolist()
        if rng.random() < 0.3:  # near-parallel lines: stations almost on one line
            ys = (np.asarray(xs) * 0.5 + rng.normal(0, 1e-3, n)).tolist()
        phis = rng.uniform(-np.pi, np.pi, n).tolist()
        ws = (1.0 / np.deg2rad(rng.uniform(0.2, 20, n)) ** 2).tolist()
        if rng.random() < 0.3:  # padded columns, as the batch path has them
            xs[-1] = ys[-1] = phis[-1] = ws[-1] = 0.0
        px, py = (rng.uniform(-1, 1, 2) * scale * rng.uniform(0.01, 3)).tolist()
        if rng.random() < 0.1:  # on a station
            px, py = xs[0], ys[0]
        yield px, py, xs, ys, phis, ws


def _cost_tolerance(ws: list[float]) -> float:
    """Absolute bound on a cost's change from residuals a few ulp of π apart."""
    return 2 * np.pi * 1e-14 * sum(ws)


@pytest.mark.parametrize("seed", range(3))
def test_trial_cost_is_the_sum_over_the_residuals(seed: int) -> None:
    for px, py, xs, ys, phis, ws in _problems(seed):
        _, _, r = tri._resid_one(px, py, xs, ys, phis)
        want = sum(w * v * v for w, v in zip(ws, r, strict=True))
        got = tri._trial_cost(px, py, xs, ys, phis, ws)
        assert got == pytest.approx(want, rel=1e-12, abs=_cost_tolerance(ws))


@pytest.mark.parametrize("seed", range(3))
def test_row_cost_is_the_row_sum_and_the_array_cost(seed: int) -> None:
    for px, py, xs, ys, phis, ws in _problems(seed):
        _, _, r = tri._row_geometry(px, py, xs, ys, phis)
        want = tri._sum([w * v * v for w, v in zip(ws, r, strict=True)])
        got = tri._row_cost(px, py, xs, ys, phis, ws)
        assert got == pytest.approx(want, rel=1e-12, abs=_cost_tolerance(ws))
        array = tri._cost(
            np.array([[px, py]]),
            np.stack([xs, ys], axis=-1)[None],
            np.array([phis]),
            np.array([ws]),
        )
        assert float(array[0]) == pytest.approx(got, rel=1e-12, abs=_cost_tolerance(ws))
