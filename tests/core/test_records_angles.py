"""Records, MAC text forms and angle conventions."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest

from rfsas_hw.angles import (
    compass_to_math_rad,
    math_rad_to_compass,
    relative_to_compass,
    wrap_deg_180,
    wrap_deg_360,
)
from rfsas_hw.errors import DataFormatError
from rfsas_hw.records import (
    NO_SEQ,
    BearingBatch,
    FrameKind,
    Observation,
    ObservationBatch,
    ObsFlag,
    int_to_mac,
    mac_to_int,
)


def test_mac_text_round_trip() -> None:
    for text in ("aa:bb:cc:dd:ee:ff", "AA-BB-CC-DD-EE-FF", "aabb.ccdd.eeff", "aabbccddeeff"):
        assert int_to_mac(mac_to_int(text)) == "aa:bb:cc:dd:ee:ff"
    with pytest.raises(DataFormatError, match="not a MAC"):
        mac_to_int("aa:bb:cc")
    with pytest.raises(DataFormatError, match="not a MAC"):
        mac_to_int("zz:bb:cc:dd:ee:ff")


def test_batch_from_rows_and_back() -> None:
    rows = [
        Observation(1, 0xA, 2437, 6, (-50.0, -55.0), 12, FrameKind.BEACON, ObsFlag.RETRY),
        Observation(2, 0xB, 5180, 36, (-60.0,), None, FrameKind.DATA),
    ]
    batch = ObservationBatch.from_observations(rows)
    assert len(batch) == 2 and batch.n_antennas == 2
    assert batch.seq.tolist() == [12, NO_SEQ]
    back = list(batch)
    assert back[0] == rows[0]
    assert back[1].seq is None and np.isnan(back[1].rssi_dbm[1])
    both = ObservationBatch.concat([batch, batch.select(np.array([False, True]))])
    assert both.mac.tolist() == [0xA, 0xB, 0xB]


def test_select_keeps_dtypes_and_contiguous_columns() -> None:
    # select takes the picked rows as they are: they must be what the checking
    # constructor would have made of them (same dtypes, contiguous, one length)
    n = 7
    obs = ObservationBatch(
        t_ns=np.arange(n),
        mac=np.arange(n) + 0xA0,
        freq_mhz=np.full(n, 2437),
        channel=np.full(n, 6),
        rssi_dbm=np.arange(2.0 * n).reshape(n, 2),
        seq=np.arange(n),
        kind=np.zeros(n),
        flags=np.ones(n),
    )
    brg = BearingBatch(
        "rsu",
        np.arange(n),
        np.arange(n) * 10.0,
        [2.0] * n,
        [20.0] * n,
        [6] * n,
        np.arange(n, dtype=np.uint64),
    )
    picks = [np.arange(n) % 2 == 0, np.array([5, 1, 1]), slice(2, 5), slice(None), slice(0, n, 3)]
    for pick in picks:
        for batch in (obs, brg):
            # every array field of the batch (the CSI block and the sensor id are not rows)
            names = [f.name for f in fields(batch) if f.name not in ("csi", "sensor_id")]
            got = batch.select(pick)
            assert type(got) is type(batch)
            for name in names:
                col, whole = getattr(got, name), getattr(batch, name)
                assert col.dtype == whole.dtype, name
                assert col.flags.c_contiguous, (name, pick)
                assert len(col) == len(got) == len(whole[pick])
                np.testing.assert_array_equal(col, whole[pick])
    assert brg.select(slice(1, 3)).sensor_id == "rsu"
    assert obs.select(np.array([], np.intp)).rssi_dbm.shape == (0, 2)


def test_batch_rejects_ragged_columns() -> None:
    with pytest.raises(ValueError, match="column 'mac' has 1 rows, expected 2"):
        ObservationBatch(
            t_ns=np.zeros(2, np.int64),
            mac=np.zeros(1, np.uint64),
            freq_mhz=np.zeros(2),
            channel=np.zeros(2),
            rssi_dbm=np.zeros((2, 2)),
        )


def test_bearing_rows_carry_hex_ids() -> None:
    b = BearingBatch("rsu", [5], [10.0], [2.0], [20.0], [6], np.array([0xDEADBEEF], np.uint64))
    row = b.row(0)
    assert row.emitter == "00000000deadbeef"
    assert np.isnan(row.relative_deg)


def test_angle_conventions() -> None:
    # north is +90° math, east is 0 rad
    assert compass_to_math_rad(0.0) == pytest.approx(np.pi / 2)
    assert compass_to_math_rad(90.0) == pytest.approx(0.0)
    assert math_rad_to_compass(np.pi) == pytest.approx(270.0)
    az = np.linspace(0, 359.9, 100)
    assert np.allclose(math_rad_to_compass(compass_to_math_rad(az)), az)
    assert wrap_deg_180(190.0) == pytest.approx(-170.0)
    assert wrap_deg_180(-180.0) == pytest.approx(180.0)
    assert wrap_deg_360(-1e-20) == 0.0
    assert relative_to_compass(-10.0, 5.0) == pytest.approx(355.0)
    assert isinstance(relative_to_compass(np.array([1.0]), 0.0), np.ndarray)
