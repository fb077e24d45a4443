"""The map: ellipse geometry, a real PNG, and a clear error without matplotlib."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from rfsas_hw.backend.plot import ellipse_axes, plot_map
from rfsas_hw.backend.service import BackendService
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.errors import BackendError
from rfsas_hw.records import BearingBatch, Pose


def test_ellipse_axes_of_known_covariances() -> None:
    assert ellipse_axes(np.diag([9.0, 1.0]), 2.0) == pytest.approx((12.0, 4.0, 0.0))
    w, h, ang = ellipse_axes(np.diag([1.0, 4.0]), 1.0)
    assert (w, h) == pytest.approx((4.0, 2.0)) and abs(abs(ang) - 90.0) < 1e-9
    # variances 5 ± 4 along the diagonals: the major axis points north-east (45°)
    w, h, ang = ellipse_axes([[5.0, 4.0], [4.0, 5.0]], 1.0)
    assert (w, h) == pytest.approx((6.0, 2.0)) and ang % 180 == pytest.approx(45.0)
    with pytest.raises(BackendError, match="finite 2×2"):
        ellipse_axes(np.array([[np.inf, 0.0], [0.0, 1.0]]))


@pytest.mark.extra("plot")
def test_map_png_from_a_service(tmp_path: Path) -> None:
    now = 1_763_800_030_000_000_000
    stations = {"a": Pose(-20.0, 0.0, 0.0), "b": Pose(20.0, 0.0, 0.0)}
    service = BackendService(vehicle=VehicleState(-15.0, 10.0, 90.0, 8.0), clock=lambda: now)
    for sid, az in (("a", 45.0), ("b", 315.0)):
        batch = BearingBatch(
            sid, np.array([now] * 2, np.int64), np.array([az, 10.0]), np.ones(2), np.ones(2),
            np.ones(2, np.int16), np.array([1, 2], np.uint64),
        )  # fmt: skip
        service.on_bearings(batch, stations[sid])
    service.step(now)
    assert {f.ok for f in service.fixes.values()} == {True, False}
    out = plot_map(
        tmp_path / "map.png",
        stations=service.stations,
        assessments=service.assessments.values(),
        fixes=service.fixes.values(),
        vehicle=service.vehicle,
    )
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000


def test_missing_matplotlib_names_the_install_command(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(BackendError, match=r"pip install 'rfsas-hw\[plot\]'"):
        plot_map(tmp_path / "x.png", stations={})
