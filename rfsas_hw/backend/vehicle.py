"""The vehicle whose risk the backend judges: its state, from a file or a UDP feed.

A vehicle state is a mapping (YAML/JSON file, or one JSON object per UDP
datagram)::

    {"x_m": -60.0, "y_m": -1.5, "heading_deg": 90.0, "speed_mps": 12.0,
     "length_m": 4.5, "width_m": 1.8, "sigma_along_m": 3.0, "sigma_across_m": 1.0,
     "t_ns": 1763800000000000000}

Only ``x_m``, ``y_m``, ``heading_deg`` and ``speed_mps`` are required; unknown
keys are refused with the file (or datagram) and the key named.
"""

from __future__ import annotations

import json
import logging
import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.angles import compass_to_math_rad
from rfsas_hw.backend.collision import (
    VEHICLE_SIGMA_ACROSS_M,
    VEHICLE_SIGMA_ALONG_M,
    VEHICLE_SIZE,
    heading_covariance,
)
from rfsas_hw.config import from_mapping, read_yaml
from rfsas_hw.errors import ConfigError, RfsasError
from rfsas_hw.link.transport import Transport, open_transport
from rfsas_hw.privacy.epochs import NS_PER_S

log = logging.getLogger(__name__)

__all__ = ["VehicleFeed", "VehicleState", "load_vehicle", "parse_vehicle"]


@dataclass(frozen=True, slots=True)
class VehicleState:
    """Where the vehicle is, where it heads and how fast, with its size and position error."""

    x_m: float
    """East position of the vehicle's centre, metres."""
    y_m: float
    """North position of the vehicle's centre, metres."""
    heading_deg: float
    """Direction of motion, compass degrees."""
    speed_mps: float
    """Speed along the heading, m/s (≥ 0)."""
    length_m: float = VEHICLE_SIZE[0]
    """Box length along the heading, metres."""
    width_m: float = VEHICLE_SIZE[1]
    """Box width across the heading, metres."""
    sigma_along_m: float = VEHICLE_SIGMA_ALONG_M
    """One-sigma position error along the heading, metres."""
    sigma_across_m: float = VEHICLE_SIGMA_ACROSS_M
    """One-sigma position error across the heading, metres."""
    t_ns: int = 0
    """Time of the state, UTC ns (0: unknown; treated as current)."""

    def __post_init__(self) -> None:
        for name in ("x_m", "y_m", "heading_deg", "speed_mps"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite, got {getattr(self, name)}")
        if self.speed_mps < 0:
            raise ValueError(f"speed_mps must be ≥ 0, got {self.speed_mps}")
        if not (self.length_m >= 0 and self.width_m >= 0):
            raise ValueError("length_m and width_m must be ≥ 0")
        if not (self.sigma_along_m >= 0 and self.sigma_across_m >= 0):
            raise ValueError("sigma_along_m and sigma_across_m must be ≥ 0")

    @property
    def position(self) -> npt.NDArray[np.float64]:
        """``(x_m, y_m)``."""
        return np.array([self.x_m, self.y_m])

    @property
    def direction(self) -> npt.NDArray[np.float64]:
        """Unit vector of the heading, east/north."""
        a = compass_to_math_rad(float(self.heading_deg))
        return np.array([math.cos(a), math.sin(a)])

    @property
    def velocity(self) -> npt.NDArray[np.float64]:
        """``(vx_mps, vy_mps)``."""
        return self.direction * self.speed_mps

    @property
    def covariance(self) -> npt.NDArray[np.float64]:
        """2×2 position covariance from the along/across sigmas, m²."""
        return heading_covariance(self.heading_deg, self.sigma_along_m, self.sigma_across_m)

    @property
    def size(self) -> tuple[float, float]:
        """``(length_m, width_m)``."""
        return (self.length_m, self.width_m)

    def at(self, t_ns: int) -> VehicleState:
        """The state moved along its heading at its speed to ``t_ns`` (UTC ns); itself
        when its time is unknown (0) or already ``t_ns``, and never moved backwards."""
        if self.t_ns in (0, t_ns):
            return self
        dt = max(t_ns - self.t_ns, 0) / NS_PER_S
        # position + velocity·dt, element by element in floats
        a = compass_to_math_rad(float(self.heading_deg))
        vx, vy = math.cos(a) * self.speed_mps, math.sin(a) * self.speed_mps
        # every field named (dataclasses.replace looks the fields up on each call)
        return VehicleState(
            float(self.x_m + vx * dt),
            float(self.y_m + vy * dt),
            self.heading_deg,
            self.speed_mps,
            self.length_m,
            self.width_m,
            self.sigma_along_m,
            self.sigma_across_m,
            t_ns,
        )


def parse_vehicle(data: Any, where: str) -> VehicleState:
    """A :class:`VehicleState` from a mapping; ``where`` names the source in errors.

    Raises:
        ConfigError: not a mapping, unknown or missing key, wrong type or range.
    """
    if not isinstance(data, dict):
        kind = type(data).__name__
        raise ConfigError(f"{where}: expected a mapping of vehicle state, got {kind}")
    return from_mapping(VehicleState, data, where)


def load_vehicle(path: str | Path) -> VehicleState:
    """Read a vehicle state from a YAML or JSON file.

    Raises:
        ConfigError: unreadable file, invalid YAML/JSON, unknown key or bad value.
    """
    return parse_vehicle(read_yaml(path), str(path))


@dataclass(slots=True)
class VehicleFeed:
    """The latest vehicle state from JSON datagrams on a UDP socket.

    Bad datagrams are counted under ``rejected`` (by reason) and skipped.
    """

    transport: Transport
    latest: VehicleState | None = None
    received: int = 0
    rejected: Counter[str] = field(default_factory=Counter)

    @classmethod
    def listen(cls, url: str) -> VehicleFeed:
        """Listen on ``url`` (``udp://host:port``).

        Raises:
            LinkError: bad URL or the socket cannot be bound.
        """
        return cls(open_transport(url, "recv"))

    def poll(self, timeout: float | None = 0.0) -> VehicleState | None:
        """Read every queued datagram (waiting ``timeout`` s for the first); return the latest."""
        datagram = self.transport.recv(timeout)
        while datagram is not None:
            self._take(datagram)
            datagram = self.transport.recv(0)
        return self.latest

    def _take(self, datagram: bytes) -> None:
        try:
            data = json.loads(datagram.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError):
            self.rejected["not_json"] += 1
            return
        try:
            self.latest = parse_vehicle(data, f"vehicle datagram {self.received + 1}")
        except RfsasError as err:
            self.rejected["bad_state"] += 1
            if self.rejected["bad_state"] == 1:
                log.warning("%s", err)
            return
        self.received += 1

    def close(self) -> None:
        """Close the socket; idempotent."""
        self.transport.close()
