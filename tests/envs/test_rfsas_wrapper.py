"""The RF-SAS wrapper: its observation, both env checkers, seeding and overlays."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from rfsas_hw.bridges.bridge import Entity
from rfsas_hw.errors import ConfigError, SimulationError
from rfsas_hw.records import Assessment

pytest.importorskip(
    "highway_env", reason="needs the highway extra: pip install 'rfsas-hw[highway]'"
)
pytest.importorskip("gymnasium", reason="needs the sim extra: pip install 'rfsas-hw[sim]'")

from rfsas_hw.bridges.highway import HighwayAdapter, idle_action, make_scene
from rfsas_hw.envs.overlay import BEARING_RGB, draw_polyline, ellipse_outline
from rfsas_hw.envs.rfsas_obs import FEATURES, encode
from rfsas_hw.envs.rfsas_wrapper import RfsasWrapper

QUIET = {"policy_frequency": 5, "initial_vehicle_count": 1, "spawn_probability": 0.0}
"""intersection-v0 with little other traffic: the tests' time goes to RF-SAS."""
WRAPPER_NOTICE = ".*is different from the unwrapped version"
"""Gymnasium's checker says so of every wrapper; all its other warnings stay errors."""


def _assessment(x: float, y: float, advisory: str, risk: float, **kw: float) -> Assessment:
    cov = {"cov_xx_m2": 4.0, "cov_xy_m2": 0.0, "cov_yy_m2": 1.0} | kw
    return Assessment(
        t_ns=0,
        emitter="00" * 8,
        x_m=x,
        y_m=y,
        vx_mps=0.0,
        vy_mps=0.0,
        age_s=0.5,
        sensors=("a", "b"),
        fix_ok=True,
        fix_reason="ok",
        p_collision=risk,
        t_closest_s=1.0,
        distance_to_contact_m=5.0,
        impact_speed_mps=3.0,
        fatality_risk=1.0,
        risk=risk,
        advisory=advisory,
        reasons=(),
        link_alarm=False,
        **cov,
    )


def test_rows_are_in_the_ego_frame_sorted_and_padded() -> None:
    ego = Entity("ego", "vehicle", 10.0, 20.0, 90.0)  # heading east
    rows = encode(
        [
            _assessment(30.0, 20.0, "caution", 0.2),  # 20 m ahead
            _assessment(10.0, 25.0, "brake", 0.1),  # 5 m to the left (north)
            _assessment(math.nan, 0.0, "brake", 1.0),  # no position: dropped
            _assessment(500.0, 20.0, "clear", 0.0),  # far ahead: clipped
        ],
        ego,
        max_emitters=4,
    )
    col = {name: i for i, name in enumerate(FEATURES)}
    assert rows.dtype == np.float32 and rows.shape == (4, len(FEATURES))
    # brake first although its risk is lower
    assert rows[0, col["advisory"]] == pytest.approx(1.0)
    assert rows[0, col["forward"]] == pytest.approx(0.0, abs=1e-6)
    assert rows[0, col["left"]] == pytest.approx(0.05)
    assert rows[1, col["forward"]] == pytest.approx(0.2)
    # east-west variance (4 m²) is the forward variance of an east-heading ego
    assert rows[1, col["cov_ff"]] == pytest.approx(0.04)
    assert rows[1, col["cov_ll"]] == pytest.approx(0.01)
    assert rows[2, col["forward"]] == pytest.approx(1.0)
    assert rows[3].tolist() == [0.0] * len(FEATURES)


def test_overlay_primitives_draw_inside_the_frame() -> None:
    frame = np.zeros((20, 30, 3), np.uint8)
    n = draw_polyline(frame, np.array([-5.0, 40.0]), np.array([10.0, 10.0]), (1, 2, 3))
    assert n > 0 and (frame[10, :, 0] == 1).all()
    e, nn = ellipse_outline(0.0, 0.0, np.array([[4.0, 0.0], [0.0, 1.0]]))
    # two-sigma axes: 4 m east-west, 2 m north-south
    assert float(e.max()) == pytest.approx(4.0) and float(nn.max()) == pytest.approx(2.0, rel=0.01)


def _wrapped(**kw: object) -> RfsasWrapper:
    return RfsasWrapper(make_scene("intersection-v0", QUIET, render_mode="rgb_array"), **kw)  # type: ignore[arg-type]


@pytest.mark.slow
def test_both_env_checkers_pass(monkeypatch: pytest.MonkeyPatch) -> None:
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    monkeypatch.setenv("SDL_AUDIODRIVER", "dummy")
    for flatten in (False, True):
        env = _wrapped(adapter="highway-env", flatten=flatten, shield=True)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error")
                warnings.filterwarnings("ignore", message=WRAPPER_NOTICE)
                check_env(env)
                if flatten:  # SB3's MlpPolicy takes the flat form
                    sb3_check_env(env, warn=True)
        finally:
            env.close()


def test_seeded_episodes_repeat_and_seeds_differ() -> None:
    def run(seed: int) -> tuple[list[np.ndarray], list[str]]:
        env = _wrapped(adapter=HighwayAdapter(), flatten=True)
        try:
            obs, _ = env.reset(seed=seed)
            out, adv = [obs], []
            for _ in range(12):
                obs, _, term, trunc, info = env.step(idle_action(env))
                out.append(obs)
                adv.append(info["rfsas"]["advisory"])
                if term or trunc:
                    break
            return out, adv
        finally:
            env.close()

    a, adv_a = run(3)
    b, adv_b = run(3)
    assert adv_a == adv_b
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    c, _ = run(4)
    assert not all(np.array_equal(x, y) for x, y in zip(a, c, strict=False))
    # the RF-SAS rows saw the crosser before the end
    rows = np.stack(a)[:, -4 * len(FEATURES) :]
    assert rows[:, 0].max() == 1.0


def test_overlay_draws_bearings_on_the_env_frame() -> None:
    env = _wrapped(adapter=HighwayAdapter())
    try:
        env.reset(seed=1)
        drawn = 0
        for _ in range(10):
            _, _, term, _, info = env.step(idle_action(env))
            plain = np.asarray(env.env.render())
            frame = np.asarray(env.render())
            assert frame.shape == plain.shape and frame.dtype == np.uint8
            # highway-env never draws this colour: every such pixel is a bearing line
            assert not np.all(plain == BEARING_RGB, axis=-1).any()
            if any(info["rfsas"]["bearings"].values()):
                drawn = max(drawn, int(np.all(frame == BEARING_RGB, axis=-1).sum()))
            if term:
                break
        assert drawn > 50
    finally:
        env.close()


def test_bad_arguments_are_named() -> None:
    inner = make_scene("intersection-v0", QUIET)
    with pytest.raises(ConfigError, match="max_emitters"):
        RfsasWrapper(inner, HighwayAdapter(), max_emitters=0)
    with pytest.raises(ConfigError, match="unknown adapter 'gazebo'"):
        RfsasWrapper(inner, "gazebo")
    env = RfsasWrapper(inner, HighwayAdapter())
    with pytest.raises(SimulationError, match="before reset"):
        env.step(1)
    env.close()
