"""The braking case: kinematics by hand, P_coll from the located pedestrian, the CLI keys."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from rfsas_hw.backend.risk import BRAKE_DECEL_MPS2
from rfsas_hw.cli.main import _load_commands, cli
from rfsas_hw.studies.braking import BrakingCase, run_braking


@pytest.fixture(scope="module")
def outcomes():
    return {d: run_braking(BrakingCase(delay_s=d)) for d in (1.5, 3.5)}


def test_short_delay_stops_long_delay_hits(outcomes) -> None:
    early, late = outcomes[1.5], outcomes[3.5]
    # front bumper to the pedestrian's near edge: 100 − 4.5/2 − 0.5/2 = 97.5 m
    stop_1_5 = 20 * 1.5 + 400 / (2 * BRAKE_DECEL_MPS2)
    assert early.stopped and early.impact_speed_mps == 0.0
    assert early.gap_at_rest_m == pytest.approx(97.5 - stop_1_5, abs=1e-9)
    assert not late.stopped
    x_b = 97.5 - 20 * 3.5
    assert late.impact_speed_mps == pytest.approx(math.sqrt(400 - 2 * BRAKE_DECEL_MPS2 * x_b))
    assert late.p_fatality == pytest.approx(
        1 / (1 + math.exp(6.9 - 0.09 * late.impact_speed_mps * 3.6))
    )
    assert late.risk == pytest.approx(late.p_collision * late.p_fatality)
    assert early.risk < 1e-3 < late.risk


def test_p_collision_follows_the_swept_path(outcomes) -> None:
    late = outcomes[3.5]
    assert np.all(np.diff(late.p_collision_t) >= -1e-12)  # the swept box only grows
    assert late.p_collision_t[0] < 1e-6
    assert late.p_collision == pytest.approx(late.p_collision_t[-1])
    assert late.p_collision > 0.1


def test_pedestrian_is_located_by_the_pipeline(outcomes) -> None:
    fix = outcomes[1.5].fix
    err = fix.position - np.array([1.75, 0.0])
    mahalanobis = float(np.sqrt(err @ np.linalg.solve(fix.covariance, err)))
    assert mahalanobis < 3.0
    assert fix.n_bearings > 40


def test_cli_json_keys() -> None:
    _load_commands()
    res = CliRunner().invoke(
        cli, ["sim", "braking", "--speed", "20", "--start", "-100", "--delay", "3.5", "--json"]
    )
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    for key in ("stopped", "impact_speed_mps", "p_collision", "p_fatality", "risk"):
        assert key in out
    assert out["stopped"] is False and out["impact_speed_mps"] > 10


def test_cli_rejects_a_start_past_the_obstacle() -> None:
    _load_commands()
    res = CliRunner().invoke(cli, ["sim", "braking", "--start", "10"])
    assert res.exit_code != 0
