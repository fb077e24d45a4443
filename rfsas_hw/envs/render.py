"""Pygame drawing of the intersection environment: a window or RGB frames.

The map shows the roads, the buildings, the car and the cross traffic with
oriented covariance ellipses (two sigma), the sensors and their lines of
bearing, the place where the warning arrives, and a gauge of the estimated
risk on a log scale with the threshold. Before the warning the cyclist is
drawn faded: the car does not know about it yet.

pygame is imported here only, and only when something is drawn.
"""

from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.angles import compass_to_math_rad
from rfsas_hw.envs.envconfig import EnvConfig
from rfsas_hw.optional import require

if TYPE_CHECKING:
    from rfsas_hw.envs.env import IntersectionEnv

Array = npt.NDArray[np.float64]

MAP_W_PX = 400
"""Width of the map, pixels."""
PANEL_W_PX = 150
"""Width of the side panel with the gauge and the numbers, pixels."""
HEIGHT_PX = 600
"""Height of the frame, pixels."""
SCALE_PX_PER_M = 5.0
"""Map scale."""
X_MIN_M = -40.0
"""West edge of the map, metres."""
Y_MAX_M = 12.0
"""North edge of the map, metres."""
RISK_FLOOR = 1e-4
"""Bottom of the risk gauge."""
ELLIPSE_SIGMAS = 2.0
"""Ellipses are drawn at this many standard deviations."""

_GRASS = (92, 124, 78)
_ROAD = (60, 60, 64)
_MARK = (230, 230, 230)
_BUILDING = (156, 146, 134)
_BUILDING_EDGE = (110, 100, 92)
_CAR = (40, 110, 220)
_OBSTACLE = (255, 140, 0)
_ESTIMATE = (220, 0, 180)
_BEARING = (0, 220, 230)
_SENSOR = (255, 230, 0)
_WARN = (255, 60, 60)
_PANEL = (28, 28, 32)
_TEXT = (235, 235, 235)


def frame_shape() -> tuple[int, int, int]:
    """Shape of an ``rgb_array`` frame: (height, width, 3)."""
    return HEIGHT_PX, MAP_W_PX + PANEL_W_PX, 3


def to_px(x_m: float, y_m: float) -> tuple[float, float]:
    """Map coordinates (metres east/north) to pixel coordinates (right/down)."""
    return (x_m - X_MIN_M) * SCALE_PX_PER_M, (Y_MAX_M - y_m) * SCALE_PX_PER_M


def ellipse_points(
    centre: Array, cov: Array, sigmas: float = ELLIPSE_SIGMAS, n: int = 40
) -> list[tuple[float, float]]:
    """Pixel outline of the ``sigmas``-sigma ellipse of a 2×2 covariance (m²) at ``centre``."""
    w, v = np.linalg.eigh(0.5 * (cov + cov.T))
    axes = sigmas * np.sqrt(np.maximum(w, 0.0))
    a = np.linspace(0.0, 2 * math.pi, n, endpoint=False)
    pts = (
        centre[None, :]
        + (np.cos(a)[:, None] * axes[0]) * v[:, 0]
        + (np.sin(a)[:, None] * axes[1]) * v[:, 1]
    )
    return [to_px(float(x), float(y)) for x, y in pts]


def box_points(
    centre: tuple[float, float], heading_deg: float, length_m: float, width_m: float
) -> list[tuple[float, float]]:
    """Pixel corners of an oriented box (length along the compass heading)."""
    a = compass_to_math_rad(heading_deg)
    u = np.array([math.cos(a), math.sin(a)]) * length_m / 2
    n = np.array([-math.sin(a), math.cos(a)]) * width_m / 2
    c = np.asarray(centre, np.float64)
    return [
        to_px(*map(float, c + su * u + sn * n)) for su, sn in ((1, 1), (1, -1), (-1, -1), (-1, 1))
    ]


class Renderer:
    """Draws :class:`~rfsas_hw.envs.env.IntersectionEnv` states.

    Args:
        config: the environment's configuration (roads, buildings, sizes).
        mode: ``human`` (a window) or ``rgb_array`` (frames).
        fps: frame rate of the window.

    Raises:
        MissingDependencyError: pygame is not installed.
    """

    def __init__(self, config: EnvConfig, mode: str, fps: int) -> None:
        os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
        self.pg: Any = require("pygame")
        self.config = config
        self.mode = mode
        self.fps = fps
        self.pg.font.init()
        self.font = self.pg.font.Font(None, 18)
        self.big = self.pg.font.Font(None, 24)
        size = (MAP_W_PX + PANEL_W_PX, HEIGHT_PX)
        self.window: Any = None
        self.clock: Any = None
        if mode == "human":
            self.pg.display.init()
            self.window = self.pg.display.set_mode(size)
            self.pg.display.set_caption("rfsas: learning to brake")
            self.clock = self.pg.time.Clock()
        self.canvas = self.pg.Surface(size)
        self.background = self._background()

    # -- static scene ------------------------------------------------------------------

    def _rect(self, x0: float, x1: float, y0: float, y1: float) -> Any:
        left, top = to_px(x0, y1)
        right, bottom = to_px(x1, y0)
        return self.pg.Rect(round(left), round(top), round(right - left), round(bottom - top))

    def _background(self) -> Any:
        pg = self.pg
        c = self.config
        surf = pg.Surface((MAP_W_PX, HEIGHT_PX))
        surf.fill(_GRASS)
        w = c.road_half_width_m
        far = 1000.0
        pg.draw.rect(surf, _ROAD, self._rect(-w, w, -far, far))
        pg.draw.rect(surf, _ROAD, self._rect(-far, far, -w, w))
        # dashed centre lines, interrupted inside the intersection
        for y in np.arange(-200.0, -w, 6.0):
            pg.draw.line(surf, _MARK, to_px(0.0, y), to_px(0.0, min(y + 3.0, -w)), 1)
        for x in np.arange(-200.0, 200.0, 6.0):
            if -w <= x <= w:
                continue
            pg.draw.line(surf, _MARK, to_px(x, 0.0), to_px(x + 3.0, 0.0), 1)
        for b in c.buildings:
            r = self._rect(b.x_min_m, b.x_max_m, b.y_min_m, b.y_max_m)
            pg.draw.rect(surf, _BUILDING, r)
            pg.draw.rect(surf, _BUILDING_EDGE, r, 2)
        return surf

    # -- dynamic scene -----------------------------------------------------------------

    def draw(self, env: IntersectionEnv) -> npt.NDArray[np.uint8] | None:
        """Draw ``env``'s current state; return the frame in ``rgb_array`` mode."""
        pg = self.pg
        canvas = self.canvas
        canvas.blit(self.background, (0, 0))
        self._draw_map(env)
        self._draw_panel(env)
        if self.mode == "human":
            self.window.blit(canvas, (0, 0))
            pg.event.pump()
            pg.display.flip()
            self.clock.tick(self.fps)
            return None
        h, w, _ = frame_shape()
        raw = pg.image.tobytes(canvas, "RGB")
        return np.frombuffer(raw, dtype=np.uint8).reshape(h, w, 3).copy()

    def _draw_map(self, env: IntersectionEnv) -> None:
        pg = self.pg
        c = self.config
        canvas = self.canvas
        v = c.vehicle
        episode = env.episode
        if episode is not None:
            y_warn = -episode.reaction_distance_m
            pg.draw.line(
                canvas, _WARN, to_px(v.lane_x_m - 3.0, y_warn), to_px(v.lane_x_m + 3.0, y_warn), 2
            )
        poses = env.sensor_poses()
        fix = env.last_fix if env.warned else None
        if fix is not None:
            for b in fix.bearings:
                a = compass_to_math_rad(b.azimuth_deg)
                end = (b.sensor_xy[0] + 150 * math.cos(a), b.sensor_xy[1] + 150 * math.sin(a))
                pg.draw.line(canvas, _BEARING, to_px(*b.sensor_xy), to_px(*end), 1)
        for pose in poses.roadside:
            pg.draw.circle(canvas, _SENSOR, [round(p) for p in to_px(pose.x_m, pose.y_m)], 4)
        # the car and its position uncertainty
        car = env.vehicle_xy()
        cov = np.diag([v.sigma_across_m**2, v.sigma_along_m**2])
        pg.draw.polygon(canvas, _CAR, box_points(car, 0.0, v.length_m, v.width_m))
        pg.draw.polygon(canvas, _CAR, ellipse_points(np.asarray(car), cov), 1)
        pg.draw.circle(canvas, _SENSOR, [round(p) for p in to_px(car[0], env.front_y_m)], 2)
        # the cross traffic: truth (faded until the warning) and the backend's estimate
        if episode is not None:
            from rfsas_hw.backend.collision import THREAT_SIZES

            length, width = THREAT_SIZES[c.obstacle.kind]
            truth = env.obstacle_xy()
            color = _OBSTACLE if env.warned else (150, 120, 80)
            pts = box_points(
                (float(truth[0]), float(truth[1])), c.obstacle.heading_deg, length, width
            )
            pg.draw.polygon(canvas, color, pts)
        if env.warned and env.track.started:
            xy, pcov, _ = env.track.predict(env.t_s)
            pg.draw.polygon(canvas, _ESTIMATE, ellipse_points(xy, pcov), 2)
            pg.draw.circle(canvas, _ESTIMATE, [round(p) for p in to_px(*map(float, xy))], 2)
            at = env.assessment
            if np.all(np.isfinite(at.obstacle_xy)):
                pg.draw.polygon(
                    canvas, _ESTIMATE, ellipse_points(at.obstacle_xy, at.obstacle_cov), 1
                )

    def _text(self, text: str, pos: tuple[int, int], big: bool = False) -> None:
        font = self.big if big else self.font
        self.canvas.blit(font.render(text, True, _TEXT), pos)

    def _draw_panel(self, env: IntersectionEnv) -> None:
        pg = self.pg
        x0 = MAP_W_PX
        pg.draw.rect(self.canvas, _PANEL, pg.Rect(x0, 0, PANEL_W_PX, HEIGHT_PX))
        a = env.assessment
        self._text(f"t {env.t_s:5.1f} s", (x0 + 8, 8), big=True)
        lines = [
            f"speed {env.speed_mps * 3.6:5.1f} km/h",
            f"to centre {env.distance_m:5.1f} m",
            f"P(coll) {a.p_collision:6.3f}",
            f"v impact {a.impact_speed_mps * 3.6:4.1f} km/h",
            f"risk {a.risk:.2e}",
            "warned" if env.warned else "no warning",
        ]
        if env.last_action is not None:
            from rfsas_hw.envs.env import ACTION_NAMES

            lines.append(f"action {ACTION_NAMES[env.last_action]}")
        if env.collided:
            lines.append(f"HIT {env.impact_speed_mps * 3.6:.0f} km/h")
        for i, line in enumerate(lines):
            self._text(line, (x0 + 8, 40 + 18 * i))
        # risk gauge, log scale from RISK_FLOOR to 1
        top, bottom = 220, HEIGHT_PX - 30
        gx = x0 + 45
        pg.draw.rect(self.canvas, (70, 70, 76), pg.Rect(gx, top, 30, bottom - top))

        def level(r: float) -> int:
            f = (math.log10(max(r, RISK_FLOOR)) - math.log10(RISK_FLOOR)) / -math.log10(RISK_FLOOR)
            return round(bottom - f * (bottom - top))

        y = level(a.risk)
        above = a.risk > self.config.risk_threshold
        pg.draw.rect(self.canvas, _WARN if above else (80, 200, 90), pg.Rect(gx, y, 30, bottom - y))
        yt = level(self.config.risk_threshold)
        pg.draw.line(self.canvas, _SENSOR, (gx - 6, yt), (gx + 36, yt), 2)
        for exp in range(-4, 1):
            yy = level(10.0**exp)
            self._text(f"1e{exp}", (x0 + 6, yy - 6))
        self._text("risk", (gx, bottom + 6))

    def close(self) -> None:
        """Close the window (if any)."""
        if self.window is not None:
            self.pg.display.quit()
            self.window = None
