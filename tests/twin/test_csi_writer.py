"""The twin's CSI: FeitCSI files that the csi: source reads back, with the geometry's phase."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rfsas_hw.df.interferometer import C_MPS, bearings, effective_snr_db, pair_phase
from rfsas_hw.errors import SimulationError
from rfsas_hw.sources.csi import capture_frames
from rfsas_hw.twin.csi_writer import CsiArray, synth_csi, write_feitcsi, write_sensor_csi
from rfsas_hw.twin.scenario import scenario_from_mapping
from rfsas_hw.twin.world import World

LAM = C_MPS / 2437e6


def test_feitcsi_round_trip(tmp_path: Path) -> None:
    array = CsiArray(baseline_m=LAM / 2)
    theta = np.array([-30.0, 0.0, 25.0])
    h = synth_csi(array, theta, 2437, np.full((3, 2), 30.0), seed=1)
    macs = np.array([0x020000000001, 0x020000000002, 0x3C22FB0102AB], np.uint64)
    rssi = np.array([[-50.0, -52.0], [-61.0, np.nan], [-40.0, -41.0]])
    t = np.array([0, 1_000_000, 2_500_000], np.int64)
    path = tmp_path / "t.csi"
    assert write_feitcsi(path, t, macs, rssi, h) == 3
    obs = capture_frames(path, freq_mhz=2437)
    assert obs.mac.tolist() == macs.tolist()
    np.testing.assert_array_equal(obs.rssi_dbm[[0, 2]], rssi[[0, 2]])
    assert np.isnan(obs.rssi_dbm[1, 1])
    assert np.diff(obs.t_ns).tolist() == [1_000_000, 1_500_000]
    assert obs.csi is not None
    got = obs.csi.h.astype(np.complex128)
    # one real scale per frame, 16-bit rounding
    ratio = got / h
    assert np.allclose(ratio.imag, 0, atol=1e-3 * np.abs(ratio).max())
    np.testing.assert_allclose(
        np.abs(ratio) / np.abs(ratio).mean(axis=(1, 2, 3))[:, None, None, None], 1, atol=0.02
    )


def test_writer_rejects_wrong_shapes(tmp_path: Path) -> None:
    h = np.zeros((2, 2, 1, 56), complex)
    with pytest.raises(SimulationError, match="disagree"):
        write_feitcsi(tmp_path / "x.csi", [0], [1, 2], np.zeros((2, 2)), h)
    with pytest.raises(SimulationError, match="expected"):
        synth_csi(CsiArray(0.06), [0.0], 2437, np.zeros((1, 3)), seed=1)


def test_sensor_capture_recovers_true_angles(tmp_path: Path) -> None:
    sc = scenario_from_mapping(
        {
            "version": 1,
            "name": "csi",
            "seed": 3,
            "duration_s": 3.0,
            "emitters": [
                {
                    "id": f"e{i}",
                    "mac": f"02:00:00:00:00:{i:02x}",
                    "tech": "wifi",
                    "tx_power_dbm": 20.0,
                    "position": [20 * math.sin(math.radians(a)), 20 * math.cos(math.radians(a))],
                    "traffic": [{"model": "beacon", "channels": [6]}],
                }
                for i, a in enumerate((-25.0, 0.0, 15.0))
            ],
            "sensors": [
                {
                    "id": "s",
                    "kind": "roadside",
                    "pose": {"x_m": 0.0, "y_m": 0.0, "heading_deg": 0.0},
                    "antenna": {"squint_deg": 15.0, "beamwidth_deg": 30.0},
                }
            ],
        },
        "<test>",
    )
    rec = World(sc).receptions("s")
    array = CsiArray(baseline_m=LAM / 2)
    path = tmp_path / "s.csi"
    rows = write_sensor_csi(rec, array, path, seed=4)
    assert len(rows) == int(rec.heard.any(axis=1).sum()) > 30
    obs = capture_frames(path, freq_mhz=2437)
    assert len(obs) == len(rows)
    assert set(obs.mac.tolist()) == set(rec.mac[rows].tolist())
    assert obs.csi is not None
    phase = pair_phase(obs.csi)
    snr = effective_snr_db(rec.snr_db[rows, 0], rec.snr_db[rows, 1], phase.terms)
    out = bearings(phase, 2437, array.baseline_m, snr_db=snr)
    err = out.angle_deg - rec.true_relative_deg[rows]
    assert out.valid.all()
    # every error within 5 of its own σ (the file's 16-bit rounding is far below the noise)
    assert np.all(np.abs(err) < 5 * out.sigma_deg)


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(1, 4),
    nrx=st.integers(1, 4),
    ntx=st.integers(1, 2),
    nsc=st.sampled_from([1, 30, 56, 242]),
    seed=st.integers(0, 2**32 - 1),
)
def test_feitcsi_codec_round_trip(n: int, nrx: int, ntx: int, nsc: int, seed: int) -> None:
    """Any shape and values: the reader gives back the writer's frames (one scale per frame)."""
    import tempfile

    rng = np.random.default_rng(seed)
    h = rng.normal(size=(n, nrx, ntx, nsc)) + 1j * rng.normal(size=(n, nrx, ntx, nsc))
    macs = rng.integers(1, 2**48, n, dtype=np.uint64)
    rssi = -rng.integers(20, 100, (n, nrx)).astype(float)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "x.csi"
        write_feitcsi(path, np.arange(n) * 1000, macs, rssi, h)
        obs = capture_frames(path)
    assert obs.csi is not None and obs.csi.h.shape == h.shape
    assert obs.mac.tolist() == macs.tolist()
    np.testing.assert_array_equal(obs.rssi_dbm[:, : min(nrx, 2)], rssi[:, : min(nrx, 2)])
    got = obs.csi.h.astype(np.complex128)
    scale = np.abs(got).max(axis=(1, 2, 3)) / np.abs(h).max(axis=(1, 2, 3))
    # int16 rounding moves a value by up to 0.5·√2 and the scale read from the largest
    # rounded value by as much again at full scale: within 1.5 in all
    np.testing.assert_allclose(got, h * scale[:, None, None, None], atol=1.5)
