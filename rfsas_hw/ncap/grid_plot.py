"""One picture per scenario drawn like Euro NCAP's result grids.

Each panel is one configuration: rows are the VUT's test speeds (slowest at
the bottom), columns the impact locations; each cell is filled with its
colour band (:data:`~rfsas_hw.ncap.scoring.COLOURS`) and labelled with the
median relative impact speed in km/h ("0" when avoided). The panel title
gives the configuration and its points for the scenario.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from rfsas_hw.ncap.scoring import COLOURS, CellScore
from rfsas_hw.optional import pyplot

__all__ = ["plot_scenario"]


def plot_scenario(
    name: str,
    cells: Sequence[CellScore],
    points: dict[str, dict[str, tuple[float, float]]],
    path: str | Path,
) -> Path:
    """Draw scenario ``name``'s cells of every configuration into ``path`` (PNG).

    Raises:
        MissingDependencyError: matplotlib is missing.
        ValueError: no cell of ``name`` is given.
    """
    mine = [c for c in cells if c.scenario == name]
    if not mine:
        raise ValueError(f"no cells of scenario {name!r} to draw")
    plt = pyplot()
    configs = sorted({c.config for c in mine}, key=lambda s: (s.count("/"), s))
    speeds = sorted({c.vut_speed_kmh for c in mine})
    impacts = sorted({c.impact for c in mine})
    n = len(configs)
    ncols = min(n, 3)
    nrows = -(-n // ncols)
    fig, axes = plt.subplots(
        nrows,
        ncols,
        figsize=(0.8 + (0.6 * len(impacts) + 1.6) * ncols, 0.6 + (0.4 * len(speeds) + 0.9) * nrows),
        squeeze=False,
        layout="constrained",  # keeps the figure's title clear of the panels' titles
    )
    flat = [ax for row in axes for ax in row]
    for ax in flat[n:]:
        ax.set_visible(False)
    for ax, config in zip(flat, configs, strict=False):
        by = {(c.vut_speed_kmh, c.impact): c for c in mine if c.config == config}
        for i, v in enumerate(speeds):
            for j, f in enumerate(impacts):
                c = by.get((v, f))
                colour = COLOURS[c.band] if c is not None else "#dddddd"
                ax.add_patch(plt.Rectangle((j, i), 1, 1, facecolor=colour, edgecolor="white"))
                label = "—" if c is None else f"{c.impact_kmh:.0f}"
                ax.text(j + 0.5, i + 0.5, label, ha="center", va="center", fontsize=8)
        ax.set_xlim(0, len(impacts))
        ax.set_ylim(0, len(speeds))
        ax.set_xticks([j + 0.5 for j in range(len(impacts))])
        ax.set_xticklabels([f"{round(f * 100)}%" for f in impacts], fontsize=7)
        ax.set_yticks([i + 0.5 for i in range(len(speeds))])
        ax.set_yticklabels([f"{v:g}" for v in speeds], fontsize=7)
        got, full = points.get(config, {}).get(name, (0.0, 0.0))
        ax.set_title(f"{config}\n{got:.2f} / {full:g} pts", fontsize=7)
        ax.set_aspect("equal")
        for side in ("top", "right", "left", "bottom"):
            ax.spines[side].set_visible(False)
    for row in axes:
        row[0].set_ylabel("VUT speed, km/h", fontsize=7)
    fig.suptitle(f"{name}: relative impact speed, km/h (impact location on the VUT front)",
                 fontsize=8)  # fmt: skip
    out = Path(path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
