"""Several sensors' pipelines in one call (``process_units``) give what each gives alone."""

from __future__ import annotations

import numpy as np
import pytest

from rfsas_hw.df import fit_calibration
from rfsas_hw.df.calibration import Calibration
from rfsas_hw.df.fovguard import FovGuard
from rfsas_hw.pipeline import SensorPipeline, process_units
from rfsas_hw.privacy import FixedNonce, MacHasher
from rfsas_hw.records import BearingBatch, ObservationBatch, Pose
from rfsas_hw.rf import GaussianBeamPair, ReceiverModel, rssi_pairs, turntable_sweep

ANT = GaussianBeamPair()
RX = ReceiverModel(measurement_floor_db=0.5)
T0 = 1_700_000_000 * 10**9
UNITS = 4
MACS = np.array([0x0200000000A0 + i for i in range(6)], np.uint64)


@pytest.fixture(scope="module")
def cal() -> Calibration:
    sweep = turntable_sweep(np.arange(-90.0, 90.5, 1.0), 30, -50.0, ANT, RX, seed=5)
    return fit_calibration(sweep, "linear")


def _steps(n_steps: int = 40) -> list[list[ObservationBatch]]:
    """Per step, each unit's frames: 0-14 of them (a few and many), emitters moving
    across the units' fields of view, some of them heard by several units at very
    different levels, one of them turning away (15 dB weaker) half-way."""
    rng = np.random.default_rng(11)
    steps = []
    for step in range(n_steps):
        per_unit = []
        for unit in range(UNITS):
            n = int(rng.integers(0, 15))
            mac = rng.choice(MACS[unit : unit + 3], n)  # neighbouring units share emitters
            theta = -60.0 + 3.0 * step + 10.0 * unit + rng.normal(0.0, 2.0, n)
            level = np.where(mac == MACS[2], -45.0 - 12.0 * unit, -55.0)
            level = np.where((mac == MACS[3]) & (step > n_steps // 2), level - 15.0, level)
            rssi = rssi_pairs(theta, -55.0, ANT, RX, rng) + (level + 55.0)[:, None]
            t_ns = T0 + step * 100_000_000 + np.sort(rng.integers(0, 100_000_000, n))
            per_unit.append(
                ObservationBatch(
                    t_ns=t_ns.astype(np.int64),
                    mac=mac,
                    freq_mhz=np.full(n, 2437),
                    channel=np.full(n, 6),
                    rssi_dbm=rssi.astype(np.float32),
                )
            )
        steps.append(per_unit)
    return steps


def _pipelines(cal: Calibration, shared: FovGuard | None, keyed: bool) -> list[SensorPipeline]:
    hasher = MacHasher(FixedNonce(b"n" * 32))
    return [
        SensorPipeline(
            cal,
            hasher,
            f"rsu-{k}",
            Pose(10.0 * k, 0.0, 90.0 * k),
            fov_guard=shared,
            guard_key=(k + 1) << 48 if keyed else 0,
        )
        for k in range(UNITS)
    ]


def _same(a: BearingBatch, b: BearingBatch) -> None:
    assert len(a) == len(b)
    np.testing.assert_array_equal(a.t_ns, b.t_ns)
    np.testing.assert_array_equal(a.emitter, b.emitter)
    np.testing.assert_allclose(a.azimuth_deg, b.azimuth_deg, atol=1e-4)
    np.testing.assert_allclose(a.sigma_deg, b.sigma_deg, rtol=1e-4)
    np.testing.assert_allclose(a.snr_db, b.snr_db, atol=1e-4)


def test_units_together_give_the_bearings_of_each_alone(cal: Calibration) -> None:
    alone = _pipelines(cal, None, keyed=False)
    together = _pipelines(cal, FovGuard(), keyed=True)
    total = 0
    for per_unit in _steps():
        solo = [p.process(b) for p, b in zip(alone, per_unit, strict=True)]
        joint = process_units(list(zip(together, per_unit, strict=True)))
        for a, b in zip(solo, joint, strict=True):
            _same(a, b)
            total += len(a)
    assert total > 500
    for a, b in zip(alone, together, strict=True):
        assert a.stats.bearings == b.stats.bearings
        assert a.stats.rejected == b.stats.rejected
    # the level rule did refuse bearings, so its state per unit and emitter was exercised
    assert sum(sum(p.stats.rejected.values()) for p in alone) > 20


def test_a_shared_guard_needs_a_key_per_unit(cal: Calibration) -> None:
    alone = _pipelines(cal, None, keyed=False)
    mixed = _pipelines(cal, FovGuard(), keyed=False)  # one guard, the units' emitters mixed
    for per_unit in _steps():
        for p, b in zip(alone, per_unit, strict=True):
            p.process(b)
        process_units(list(zip(mixed, per_unit, strict=True)))
    assert [p.stats.rejected for p in alone] != [p.stats.rejected for p in mixed]


def test_guard_key_must_leave_the_mac_alone(cal: Calibration) -> None:
    hasher = MacHasher(FixedNonce(b"n" * 32))
    for bad in (1, 3 << 47, 1 << 64, -(1 << 48)):
        with pytest.raises(ValueError, match="guard_key"):
            SensorPipeline(cal, hasher, "rsu-1", Pose(0.0, 0.0, 0.0), guard_key=bad)


def test_empty_and_single_chain_batches_keep_their_place(cal: Calibration) -> None:
    pipes = _pipelines(cal, FovGuard(), keyed=True)
    full = _steps(1)[0][0]
    one_chain = ObservationBatch(
        t_ns=full.t_ns,
        mac=full.mac,
        freq_mhz=full.freq_mhz,
        channel=full.channel,
        rssi_dbm=full.rssi_dbm[:, :1],
    )
    out = process_units(
        [(pipes[0], ObservationBatch.empty()), (pipes[1], one_chain), (pipes[2], full)]
    )
    assert [b.sensor_id for b in out] == ["rsu-0", "rsu-1", "rsu-2"]
    assert len(out[0]) == 0 and len(out[1]) == 0 and len(out[2]) > 0
    assert pipes[1].stats.rejected["missing_chain"] == len(full)
    with pytest.raises(ValueError, match="one batch per pipeline"):
        process_units([(pipes[2], full), (pipes[2], full)])
