"""The sensor pipeline's shortcuts for a few frames give what the general code gives."""

from __future__ import annotations

import numpy as np

from rfsas_hw.angles import relative_to_compass
from rfsas_hw.df.lut import UniformLut
from rfsas_hw.pipeline import _to_compass


def test_compass_azimuths_equal_relative_to_compass_bit_for_bit() -> None:
    rng = np.random.default_rng(3)
    rel = np.concatenate([rng.uniform(-90, 90, 500), [-1e-14, 0.0, -0.0, 90.0, -90.0]])
    for heading in (0.0, 170.0, 225.0, 290.0, 359.999999, float(rng.uniform(0, 360))):
        got = _to_compass(rel, heading)
        want = relative_to_compass(rel, heading)
        assert got.dtype == want.dtype == np.float64
        np.testing.assert_array_equal(got, want)
        assert ((got >= 0.0) & (got < 360.0)).all()


def test_lookup_inside_and_outside_the_table_and_nan() -> None:
    x = np.linspace(-10.0, 10.0, 41)
    lut = UniformLut.tabulate(x, np.linspace(-60.0, 60.0, 41), np.linspace(1.0, 2.0, 41))
    inside = np.array([-9.5, 0.25, 9.9], np.float32)
    a_in, f_in, out_in = lut(inside)
    assert not out_in.any()
    mixed = np.array([-9.5, 0.25, 9.9, np.nan, 50.0], np.float32)
    a_mix, f_mix, out_mix = lut(mixed)  # no warning for the NaN (warnings are errors here)
    np.testing.assert_array_equal(out_mix, [False, False, False, True, True])
    np.testing.assert_array_equal(a_mix[:3], a_in)
    np.testing.assert_array_equal(f_mix[:3], f_in)
