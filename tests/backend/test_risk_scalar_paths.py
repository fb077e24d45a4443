"""The plain-float paths of stopping distance and impact speed equal the array paths.

Within round-off (rtol 1e-12), not bit for bit: numpy's vectorised kernels need not
round as :mod:`math` does on every CPU.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from rfsas_hw.angles import compass_to_math_rad, math_rad_to_compass, wrap_deg_180
from rfsas_hw.backend.risk import BRAKE_DECEL_MPS2, impact_speed, stopping_distance
from rfsas_hw.errors import BackendError


def _same(a: float, b: float) -> bool:
    return math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-300) or (math.isnan(a) and math.isnan(b))


def test_one_speed_in_floats_equals_the_array_path() -> None:
    rng = np.random.default_rng(12)
    edges = [(0.0, 0.0), (-0.0, -0.0), (1e-300, 1e-9), (13.9, -3.0), (30.0, 1e300), (5.0, 2.5)]
    cases = edges + [(float(u), float(x)) for u, x in rng.uniform([0, -5], [40, 80], (3000, 2))]
    for k, (u, x) in enumerate(cases):
        decel = BRAKE_DECEL_MPS2 if k % 2 else float(rng.uniform(1.0, 9.0))
        tau = (0.0, 0.2, 0.5, float(rng.uniform(0.0, 1.0)))[k % 4]
        d = stopping_distance(u, decel, tau)
        v = impact_speed(u, x, decel, tau)
        assert type(d) is float and type(v) is float
        assert _same(d, float(stopping_distance(np.array([u]), decel, tau)[0]))
        assert _same(v, float(impact_speed(np.array([u]), np.array([x]), decel, tau)[0]))


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: stopping_distance(-1.0), "speed must be"),
        (lambda: impact_speed(math.nan, 1.0), "speed must be"),
        (lambda: impact_speed(1.0, math.inf), "distance must be finite"),
        (lambda: stopping_distance(1.0, 0.0), "braking deceleration"),
        (lambda: impact_speed(1.0, 1.0, 2.0, -1.0), "reaction delay"),
    ],
)
def test_one_speed_is_checked_as_an_array_is(call: object, message: str) -> None:
    with pytest.raises(BackendError, match=message):
        call()  # type: ignore[operator]


def test_angle_conversions_of_one_float_equal_the_array_functions() -> None:
    rng = np.random.default_rng(13)
    az = np.concatenate(
        [rng.uniform(-720, 720, 20000), rng.normal(0, 1e-12, 200), [0.0, -0.0, 90.0, 360.0]]
    )
    want = compass_to_math_rad(az)
    got = np.array([compass_to_math_rad(float(a)) for a in az])
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    rad = np.concatenate([rng.uniform(-7, 7, 20000), [0.0, -0.0, math.pi, -math.pi, 1e-300]])
    want = math_rad_to_compass(rad)
    got = np.array([math_rad_to_compass(float(a)) for a in rad])
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    want = wrap_deg_180(az)
    got = np.array([wrap_deg_180(float(a)) for a in az])
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
