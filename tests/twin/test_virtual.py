"""``virtual:`` specs, poses of moving sensors, and bearings through the real pipeline."""

from __future__ import annotations

import numpy as np
import pytest

from rfsas_hw.angles import wrap_deg_180
from rfsas_hw.df import load_calibration
from rfsas_hw.errors import ConfigError
from rfsas_hw.pipeline import SensorPipeline
from rfsas_hw.privacy.hashing import FixedNonce, MacHasher
from rfsas_hw.sources import open_source
from rfsas_hw.twin.turntable import turntable_calibration

from .conftest import EXAMPLE


def test_spec_names_the_sensor() -> None:
    with pytest.raises(ConfigError, match="name the sensor"):
        open_source(f"virtual:{EXAMPLE}")
    with pytest.raises(ConfigError, match="no sensor 'nope'"):
        open_source(f"virtual:{EXAMPLE}#nope")
    with pytest.raises(ConfigError, match="cannot read"):
        open_source("virtual:/nonexistent/scenario.yaml#a")


def test_on_board_pose_follows_the_car(example) -> None:
    with open_source(f"virtual:{EXAMPLE}#car-obu") as src:
        p0 = src.pose_at(src.world.t0_ns)
        p1 = src.pose_at(src.world.t0_ns + 2_000_000_000)
    assert (p0.x_m, p0.y_m) == pytest.approx((1.75, -165.0))
    assert p1.y_m - p0.y_m == pytest.approx(40.0)
    assert p1.heading_deg == pytest.approx(10.0)  # north + the 10° mounting offset


def test_bundled_calibrations_are_the_simulated_turntable_runs(example) -> None:
    for sensor in ("rsu-nw", "car-obu"):
        path = example.calibration_path(sensor)
        assert path is not None
        bundled = load_calibration(path)
        fresh = turntable_calibration(example, sensor)
        assert bundled.mode == fresh.mode == "linear"
        np.testing.assert_allclose(bundled.tables[0].psi, fresh.tables[0].psi, atol=1e-6)


def test_roadside_bearings_are_within_their_sigma(example) -> None:
    """Twin → real DF: bearing errors are consistent with the σ the pipeline reports."""
    path = example.calibration_path("rsu-nw")
    assert path is not None
    with open_source(f"virtual:{EXAMPLE}#rsu-nw") as src:
        rec = src.world.receptions("rsu-nw")
        pipe = SensorPipeline(
            load_calibration(path), MacHasher(FixedNonce(b"k" * 16)), "rsu-nw", src.pose_at(0)
        )
        out = [pipe.process(b) for b in src]
    az = np.concatenate([b.azimuth_deg for b in out])
    sigma = np.concatenate([b.sigma_deg for b in out])
    t_ns = np.concatenate([b.t_ns for b in out])
    row = np.searchsorted(rec.capture_ns[:, 0], t_ns)
    assert np.all(rec.capture_ns[row, 0] == t_ns)
    # the phone, in front of the unit (the corner AP behind it aliases, as it would for real)
    phone = rec.emitter[row] == 0
    z = wrap_deg_180(az - rec.true_azimuth_deg[row])[phone] / sigma[phone]
    assert len(z) > 100
    assert 0.7 < np.std(z) < 1.4
    assert np.mean(np.abs(z) < 3) > 0.97


class FakeTime:
    """A clock that only moves when slept on."""

    def __init__(self) -> None:
        self.now = 100.0
        self.slept: list[float] = []

    def clock(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.slept.append(seconds)
        self.now += seconds


def test_realtime_paces_batches_by_scenario_time() -> None:
    from rfsas_hw.sources.virtual import VirtualSource

    from .conftest import small

    fake = FakeTime()
    src = VirtualSource(
        small(), "rsu", batch_s=0.5, realtime=True, clock=fake.clock, sleep=fake.sleep
    )
    with src:
        n = sum(1 for _ in src)
    assert n >= 5
    # a 3 s scenario replayed in real time takes 3 s of (fake) waiting
    assert sum(fake.slept) == pytest.approx(3.0)
    fake2 = FakeTime()
    src2 = VirtualSource(
        small(), "rsu", batch_s=0.5, realtime=True, clock=fake2.clock, sleep=fake2.sleep
    )
    with src2:
        assert src2.read(timeout=0.1) is None  # not due yet: waited the timeout only
    assert fake2.slept == [0.1]


def test_physical_two_ray_models_in_the_world() -> None:
    from rfsas_hw.rf.propagation import path_loss_db
    from rfsas_hw.twin.world import World

    from .conftest import small

    for model in ("breakpoint", "coherent"):
        world = World(small(detail="low", rf={"path_loss": model}))
        rec = world.receptions("rsu")
        want_pl = path_loss_db(rec.distance_m, model, freq_mhz=2437.0)
        ant = world.antennas["rsu"]
        pt = np.where(rec.emitter == 1, 20.0, 27.0) + 3.0
        want = (pt - want_pl - 15.0)[:, None] + ant.gains_db(rec.true_relative_deg)
        np.testing.assert_allclose(rec.chain_dbm, want, atol=1e-9)
