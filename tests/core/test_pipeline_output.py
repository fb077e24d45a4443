"""Observations through DF and hashing to bearings, and the bearing writers."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np
import pytest

from rfsas_hw.df import fit_calibration
from rfsas_hw.output import BearingWriter
from rfsas_hw.pipeline import SensorPipeline
from rfsas_hw.privacy import FixedNonce, MacHasher, hash_mac
from rfsas_hw.records import ObservationBatch, Pose, int_to_mac
from rfsas_hw.rf import GaussianBeamPair, ReceiverModel, rssi_pairs, turntable_sweep

ANT = GaussianBeamPair()
RX = ReceiverModel(measurement_floor_db=0.5)
KEY = b"k" * 32


@pytest.fixture(scope="module")
def pipeline() -> SensorPipeline:
    sweep = turntable_sweep(np.arange(-90.0, 90.5, 1.0), 30, -50.0, ANT, RX, seed=5)
    cal = fit_calibration(sweep, "linear")
    return SensorPipeline(cal, MacHasher(FixedNonce(KEY)), "rsu-1", Pose(10.0, -5.0, 300.0))


def _observations(theta: np.ndarray, macs: np.ndarray) -> ObservationBatch:
    rssi = rssi_pairs(theta, -55.0, ANT, RX, np.random.default_rng(9))
    n = len(theta)
    return ObservationBatch(
        t_ns=np.arange(n, dtype=np.int64) * 1_000_000 + 1_700_000_000_000_000_000,
        mac=macs,
        freq_mhz=np.full(n, 2437),
        channel=np.full(n, 6),
        rssi_dbm=rssi,
    )


def test_bearings_are_compass_azimuths_with_hashed_ids(pipeline: SensorPipeline) -> None:
    theta = np.repeat(np.array([-20.0, 0.0, 25.0]), 400)
    macs = np.repeat(np.array([0x0200000000A1, 0x0200000000B2, 0x0200000000C3], np.uint64), 400)
    out = pipeline.process(_observations(theta, macs))
    assert len(out) == 1200
    for mac, rel in ((0x0200000000A1, -20.0), (0x0200000000B2, 0.0), (0x0200000000C3, 25.0)):
        sel = out.emitter == np.uint64(hash_mac(KEY, mac))
        assert sel.sum() == 400
        # compass = boresight 300° + relative; the mean of 400 bearings is within 0.5°
        assert np.mean(out.relative_deg[sel]) == pytest.approx(rel, abs=0.5)
        expected = (300.0 + rel) % 360.0
        assert np.mean(out.azimuth_deg[sel]) == pytest.approx(expected, abs=0.5)
    assert pipeline.stats.bearings == 1200 and len(pipeline.stats.emitters) == 3


def test_invalid_frames_are_counted_not_emitted(pipeline: SensorPipeline) -> None:
    obs = _observations(np.zeros(3), np.arange(3, dtype=np.uint64))
    obs.rssi_dbm[0, 1] = np.nan
    obs.rssi_dbm[1, :] = [-20.0, -70.0]
    before = dict(pipeline.stats.rejected)
    out = pipeline.process(obs)
    assert len(out) == 1
    assert pipeline.stats.rejected["missing_chain"] == before.get("missing_chain", 0) + 1
    assert pipeline.stats.rejected["outside_fov"] >= before.get("outside_fov", 0) + 1


def test_writers_hold_ids_not_macs(pipeline: SensorPipeline, tmp_path: Path) -> None:
    macs = np.array([0x0A1B2C3D4E5F] * 5, np.uint64)
    out = pipeline.process(_observations(np.zeros(5), macs))
    for name in ("b.jsonl", "b.csv"):
        writer = BearingWriter(tmp_path / name)
        writer.on_bearings(out)
        writer.close()
        text = (tmp_path / name).read_text()
        assert "0a:1b:2c" not in text.lower() and "0a1b2c3d4e5f" not in text.lower()
    rows = [json.loads(line) for line in (tmp_path / "b.jsonl").read_text().splitlines()]
    assert rows[0]["emitter"] == f"{hash_mac(KEY, 0x0A1B2C3D4E5F):016x}"
    assert rows[0]["sensor_id"] == "rsu-1"
    with (tmp_path / "b.csv").open() as handle:
        assert len(list(csv.DictReader(handle))) == 5
    stream = io.StringIO()
    w = BearingWriter(stream)
    w.on_bearings(out)
    w.close()
    assert len(stream.getvalue().splitlines()) == 5
    assert int_to_mac(0x0A1B2C3D4E5F) not in stream.getvalue()
