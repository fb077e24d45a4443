"""The scenario grid: one panel per configuration, and the figure's title clear of the
panels' titles (it overlapped the top-middle panel's)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from rfsas_hw.ncap.grid_plot import plot_scenario
from rfsas_hw.ncap.scoring import CellScore

pytest.importorskip("matplotlib")


def _cells(configs: list[str]) -> list[CellScore]:
    return [
        CellScore("CPNCO", f"CPNCO-{f}@{v}", v, f / 100, config, 0.0, "green", 1.0, 1, 0)
        for config in configs
        for v in (10.0, 20.0, 30.0, 40.0, 50.0, 60.0)
        for f in (25, 50, 75)
    ]


def test_the_title_does_not_cover_a_panel_title(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from matplotlib.figure import Figure

    seen: list[tuple[Any, list[Any]]] = []
    save = Figure.savefig

    def keep(fig: Figure, *args: Any, **kwargs: Any) -> None:
        save(fig, *args, **kwargs)  # lays the figure out and draws it
        renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
        titles = [ax.title.get_window_extent(renderer) for ax in fig.axes if ax.get_visible()]
        seen.append((fig._suptitle.get_window_extent(renderer), titles))  # type: ignore[union-attr]

    monkeypatch.setattr(Figure, "savefig", keep)
    configs = ["los"] + [
        f"{c}/{d}/{p}"
        for c in ("los+cue", "rfsas+los", "rfsas")
        for d in ("car", "car+rsu")
        for p in ("phone-active", "phone-idle")
    ]
    points = {c: {"CPNCO": (1.0, 2.0)} for c in configs}
    out = plot_scenario("CPNCO", _cells(configs), points, tmp_path / "CPNCO.png")
    assert out.read_bytes()[:4] == b"\x89PNG"
    ((title, panels),) = seen
    assert len(panels) == 13
    assert not any(title.overlaps(p) for p in panels)
