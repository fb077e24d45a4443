"""The sensor pipeline's shortcuts for a few frames give what the general code gives."""

from __future__ import annotations

import numpy as np
import pytest

from rfsas_hw import pipeline
from rfsas_hw.df import fit_calibration
from rfsas_hw.df.estimate import estimate
from rfsas_hw.df.fovguard import FovGuard, boresight_levels
from rfsas_hw.df.lut import UniformLut
from rfsas_hw.pipeline import DF_MEMO_ROWS, SensorPipeline, _DfMemo
from rfsas_hw.privacy.hashing import FixedNonce, MacHasher
from rfsas_hw.records import ObservationBatch, Pose
from rfsas_hw.rf import GaussianBeamPair, ReceiverModel, turntable_sweep
from rfsas_hw.rf.synth import TurntableSamples

RX = ReceiverModel(measurement_floor_db=0.5)
T0 = 1_700_000_000 * 10**9


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


def _quantised_batch(
    rng: np.random.Generator,
    n: int,
    channels: tuple[int, ...],
    lo: float = -95.0,
    hi: float = -15.0,
) -> ObservationBatch:
    """RSSI in half dB as drivers report it, with some missing chains and strong frames."""
    rssi = np.round(rng.uniform(lo, hi, (n, 2)) * 2) / 2
    rssi[rng.random((n, 2)) < 0.05] = np.nan
    return ObservationBatch(
        t_ns=T0 + np.arange(n, dtype=np.int64) * 1_000_000,
        mac=np.full(n, 0x0200000000A1, np.uint64),
        freq_mhz=np.full(n, 2437),
        channel=rng.choice(channels, n),
        rssi_dbm=rssi.astype(np.float32),
    )


@pytest.mark.parametrize("mode", ["linear", "db"])
def test_df_memo_gives_what_estimate_gives(mode: str) -> None:
    # tables for channels 1 and 6; channel 11 has none (NO_TABLE)
    sweeps = [
        turntable_sweep(np.arange(-90.0, 90.5, 1.0), 30, -50.0, GaussianBeamPair(), RX, 5 + c, c)
        for c in (1, 6)
    ]
    merged = TurntableSamples(
        *(np.concatenate([getattr(w, f) for w in sweeps]) for f in TurntableSamples.__annotations__)
    )
    cal = fit_calibration(merged, mode)  # type: ignore[arg-type]
    rng = np.random.default_rng(11)
    for min_snr in (None, 25.0):
        memo = _DfMemo(cal, min_snr)
        hits = 0
        for _ in range(3000):
            n = int(rng.integers(1, DF_MEMO_ROWS + 1))
            # a narrow range too, so that pairs come again; one channel or several
            lo, hi = (-95.0, -15.0) if rng.random() < 0.3 else (-60.0, -45.0)
            batch = _quantised_batch(rng, n, (1, 6, 11) if rng.random() < 0.3 else (6,), lo, hi)
            before = len(memo.rows)
            got = memo.estimate(batch)
            hits += len(memo.rows) == before
            want = estimate(
                cal, batch.rssi_dbm[:, 0], batch.rssi_dbm[:, 1], batch.channel, min_snr_db=min_snr
            )
            for name in ("angle_deg", "sigma_deg", "snr_db", "flags"):
                a, b = getattr(got, name), getattr(want, name)
                assert a.dtype == b.dtype and a.shape == b.shape, name
                # A pair's result is computed in another batch; numpy's SIMD and
                # scalar loops may differ in the last bit (float32: rtol 1e-6).
                np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6, err_msg=name)
        assert hits > 300  # the memo did answer whole batches
        assert not any(k[0] != k[0] or k[1] != k[1] for k in memo.rows)  # no NaN kept


def test_df_memo_levels_are_the_guards_levels() -> None:
    # the memo keeps each pair's boresight-equivalent level; a batch it answers gets
    # the levels the guard would compute from the result, and the guard fed them
    # refuses what it refuses computing them itself
    sweeps = [
        turntable_sweep(np.arange(-90.0, 90.5, 1.0), 30, -50.0, GaussianBeamPair(), RX, 7 + c, c)
        for c in (1, 6)
    ]
    merged = TurntableSamples(
        *(np.concatenate([getattr(w, f) for w in sweeps]) for f in TurntableSamples.__annotations__)
    )
    cal = fit_calibration(merged, "linear")
    memo = _DfMemo(cal, None)
    fed, own = FovGuard(), FovGuard()
    rng = np.random.default_rng(4)
    hits = refused = 0
    for k in range(1500):
        n = int(rng.integers(1, DF_MEMO_ROWS + 1))
        channels = (1, 6, 11) if rng.random() < 0.3 else (6,)
        lo, hi = (-95.0, -15.0) if rng.random() < 0.3 else (-60.0, -45.0)
        batch = _quantised_batch(rng, n, channels, lo, hi)
        batch = ObservationBatch(
            t_ns=batch.t_ns + k * 50_000_000,
            mac=np.full(n, 0x0200000000A1 + k % 3, np.uint64),
            freq_mhz=batch.freq_mhz,
            channel=batch.channel,
            rssi_dbm=batch.rssi_dbm,
        )
        before = len(memo.rows)
        result, levels = memo.estimate_with_levels(batch)
        hits += len(memo.rows) == before
        r1, r2 = batch.rssi_dbm[:, 0], batch.rssi_dbm[:, 1]
        want = boresight_levels(cal, result, r1, r2, batch.channel)
        np.testing.assert_allclose(levels, want, rtol=0.0, atol=1e-4)  # NaN where no bearing
        a = fed.apply(cal, result, r1, r2, batch.channel, batch.mac, batch.t_ns, levels)
        b = own.apply(cal, result, r1, r2, batch.channel, batch.mac, batch.t_ns)
        np.testing.assert_array_equal(a.flags, b.flags)
        refused += int(np.count_nonzero(a.flags != result.flags))
    assert hits > 200 and refused > 0 and fed.refused == own.refused == refused


def test_pipelines_share_a_memo_per_calibration_and_give_the_same_bearings(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    sweep = turntable_sweep(np.arange(-90.0, 90.5, 1.0), 30, -50.0, GaussianBeamPair(), RX, seed=5)
    cal = fit_calibration(sweep, "linear")
    hasher = MacHasher(FixedNonce(bytes(32)))
    rng = np.random.default_rng(2)
    batches = [_quantised_batch(rng, int(rng.integers(1, 12)), (6,)) for _ in range(400)]
    outputs = []
    for rows in (DF_MEMO_ROWS, 0):
        monkeypatch.setattr(pipeline, "DF_MEMO_ROWS", rows)
        a = SensorPipeline(cal, hasher, "a", Pose(0.0, 0.0, 30.0))
        b = SensorPipeline(cal, hasher, "b", Pose(0.0, 0.0, 30.0), min_snr_db=20.0)
        outputs.append([(a.process(x), b.process(x)) for x in batches])
        if rows:
            c = SensorPipeline(cal, hasher, "c", Pose(0.0, 0.0, 30.0))
            c.process(_quantised_batch(rng, 2, (6,)))
            assert a._memo is c._memo and a._memo is not b._memo
    for (a1, b1), (a0, b0) in zip(*outputs, strict=True):
        for got, want in ((a1, a0), (b1, b0)):
            for name in ("t_ns", "emitter"):
                np.testing.assert_array_equal(getattr(got, name), getattr(want, name), name)
            for name in ("azimuth_deg", "sigma_deg", "snr_db", "relative_deg"):
                a, b = getattr(got, name), getattr(want, name)
                np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-4, err_msg=name)


def test_df_memo_learns_the_neighbours_of_a_new_pair() -> None:
    # a miss also computes the pairs up to DF_MEMO_REACH steps around the new one (in
    # the same estimate call), so the next readings of a moving emitter are answered
    sweep = turntable_sweep(np.arange(-90.0, 90.5, 1.0), 30, -50.0, GaussianBeamPair(), RX, seed=3)
    cal = fit_calibration(sweep, "linear")
    memo = _DfMemo(cal, None)

    def batch(pairs: list[tuple[float, float]]) -> ObservationBatch:
        n = len(pairs)
        return ObservationBatch(
            t_ns=T0 + np.arange(n, dtype=np.int64),
            mac=np.full(n, 0x0200000000A1, np.uint64),
            freq_mhz=np.full(n, 2437),
            channel=np.full(n, 6),
            rssi_dbm=np.array(pairs, np.float32),
        )

    memo.estimate(batch([(-50.0, -55.0)]))
    side = 2 * pipeline.DF_MEMO_REACH + 1
    assert len(memo.rows) == side * side
    step, reach = cal.step_db, pipeline.DF_MEMO_REACH
    near = batch([(-50.0 - reach * step, -55.0 + step), (-50.0 + step, -55.0 + reach * step)])
    got = memo.estimate(near)
    assert len(memo.rows) == side * side  # answered from the memo
    r = near.rssi_dbm
    want = estimate(cal, r[:, 0], r[:, 1], near.channel)
    for name in ("angle_deg", "sigma_deg", "snr_db", "flags"):
        a, b = getattr(got, name), getattr(want, name)
        assert a.dtype == b.dtype
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6, err_msg=name)
    memo.estimate(batch([(-50.0 - (reach + 1) * step, -55.0)]))  # just outside: a miss
    assert len(memo.rows) > side * side
