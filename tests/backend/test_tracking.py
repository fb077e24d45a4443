"""Constant-velocity tracking over successive fixes."""

from __future__ import annotations

import numpy as np
import pytest

from rfsas_hw.backend.tracking import Tracker, TrackerConfig
from rfsas_hw.errors import BackendError

S = 1_000_000_000


def test_walking_emitter_velocity_is_recovered_and_covariance_is_consistent() -> None:
    rng = np.random.default_rng(30)
    v_true = np.array([1.2, -0.5])
    R = np.array([[4.0, 1.0], [1.0, 2.0]])
    Lr = np.linalg.cholesky(R)
    nees = []
    errs = []
    for run in range(200):
        tracker = Tracker(TrackerConfig(accel_sigma_mps2=0.05))
        for k in range(40):
            t = k * S // 2
            truth = np.array([10.0, 5.0]) + v_true * (k / 2)
            z = truth + Lr @ rng.standard_normal(2)
            track = tracker.update(7, t, z, R)
        e = track.position - truth
        nees.append(float(e @ np.linalg.solve(track.position_cov, e)))
        errs.append(track.velocity - v_true)
        assert tracker.stats.restarted == 0 or run > 0
    # filtered position better than one fix, velocity close, NEES near 2
    assert np.mean(nees) == pytest.approx(2.0, abs=0.45)
    assert np.linalg.norm(np.mean(errs, axis=0)) < 0.05
    assert np.sqrt(np.mean(np.sum(np.square(errs), 1))) < 0.3


def test_gate_restarts_out_of_order_ignored_and_stale_dropped() -> None:
    tracker = Tracker(TrackerConfig(drop_after_s=5.0))
    eye = np.eye(2)
    tracker.update(1, 0, np.array([0.0, 0.0]), eye, ("a", "b"))
    tracker.update(1, S, np.array([0.5, 0.0]), eye)
    assert tracker.stats.updated == 1
    jumped = tracker.update(1, 2 * S, np.array([300.0, 0.0]), eye)
    assert tracker.stats.restarted == 1 and jumped.updates == 1
    np.testing.assert_allclose(jumped.position, [300.0, 0.0])
    tracker.update(1, S, np.array([0.0, 0.0]), eye)
    assert tracker.stats.out_of_order == 1
    tracker.update(2, 6 * S, np.array([1.0, 1.0]), eye)
    assert tracker.prune(8 * S) == [1]
    assert len(tracker) == 1 and tracker.stats.dropped == 1
    with pytest.raises(BackendError, match="finite"):
        tracker.update(3, 0, np.array([np.nan, 0.0]), eye)
    with pytest.raises(BackendError, match="accel_sigma_mps2"):
        TrackerConfig(accel_sigma_mps2=0)
