"""Pygame rendering of the environment, headless (SDL dummy video driver)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

pytest.importorskip("gymnasium", reason="needs the sim extra: pip install 'rfsas-hw[sim]'")

from rfsas_hw.envs.env import BRAKE, COAST, IntersectionEnv
from rfsas_hw.envs.render import SCALE_PX_PER_M, ellipse_points, frame_shape, to_px


@pytest.fixture(autouse=True)
def headless(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    monkeypatch.setenv("SDL_AUDIODRIVER", "dummy")


def colour_at(frame: np.ndarray, x_m: float, y_m: float) -> tuple[int, ...]:
    px, py = to_px(x_m, y_m)
    return tuple(int(c) for c in frame[round(py), round(px)])


def test_rgb_frames_have_the_right_shape_and_change_over_an_episode() -> None:
    env = IntersectionEnv({"sensing": {"detail": "medium"}}, render_mode="rgb_array")
    env.reset(seed=2, options={"reaction_distance_m": 70.0})
    frames = [env.render()]
    done = False
    while not done:
        a = BRAKE if env.assessment.risk > env.config.risk_threshold else COAST
        _, _, term, trunc, _ = env.step(a)
        done = term or trunc
        frames.append(env.render())
    assert len(frames) > 10
    for f in frames:
        assert f is not None
        assert f.shape == frame_shape() and f.dtype == np.uint8
    diffs = [np.count_nonzero(np.any(a != b, axis=2)) for a, b in itertools.pairwise(frames)]
    assert min(diffs) > 0
    assert np.any(frames[0] != frames[-1])
    env.close()


def test_the_car_is_drawn_where_it_is() -> None:
    env = IntersectionEnv(render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame is not None
    x, y = env.vehicle_xy()
    assert colour_at(frame, x, y) == (40, 110, 220)
    for _ in range(20):
        env.step(COAST)
    later = env.render()
    assert later is not None
    assert colour_at(later, x, y) != (40, 110, 220)
    x2, y2 = env.vehicle_xy()
    assert colour_at(later, x2, y2) == (40, 110, 220)


def test_human_mode_draws_into_a_window() -> None:
    env = IntersectionEnv(render_mode="human")
    env.reset(seed=0)
    assert env.render() is None
    env.step(COAST)
    env.close()
    env.close()


def test_render_without_a_mode_warns() -> None:
    env = IntersectionEnv()
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.render() is None


def test_covariance_ellipse_is_oriented_and_sized_at_two_sigma() -> None:
    # σ = 2 m east-west, 1 m north-south: the 2σ ellipse spans ±4 m in x and ±2 m in y
    pts = np.array(ellipse_points(np.zeros(2), np.diag([4.0, 1.0])))
    cx, cy = to_px(0.0, 0.0)
    assert np.ptp(pts[:, 0]) == pytest.approx(8.0 * SCALE_PX_PER_M, rel=1e-6)
    assert np.ptp(pts[:, 1]) == pytest.approx(4.0 * SCALE_PX_PER_M, rel=0.02)
    assert np.mean(pts, axis=0) == pytest.approx([cx, cy])
    # rotated 45°: equal spread on both axes
    rot = np.array([[2.5, 1.5], [1.5, 2.5]])
    pts = np.array(ellipse_points(np.zeros(2), rot))
    assert np.ptp(pts[:, 0]) == pytest.approx(np.ptp(pts[:, 1]), rel=0.02)
