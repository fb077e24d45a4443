"""Drawing a calibration: ψ_D(θ) with the turntable samples and the field of view."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rfsas_hw.df.calibration import Calibration
from rfsas_hw.df.monopulse import ratio
from rfsas_hw.optional import pyplot
from rfsas_hw.outpaths import save_figure
from rfsas_hw.rf.synth import TurntableSamples


def plot_calibration(cal: Calibration, samples: TurntableSamples | None, path: str | Path) -> None:
    """Write a PNG of every table's ψ_D curve, its FoV and (optionally) the samples' ψ.

    Raises:
        MissingDependencyError: matplotlib is not installed (the ``plot`` extra).
    """
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 5), dpi=110)
    for table in cal.tables:
        label = "all channels" if table.channel is None else f"channel {table.channel}"
        if samples is not None:
            mask = (
                np.ones(len(samples.angle_deg), bool)
                if table.channel is None
                else samples.channel == table.channel
            )
            psi_s = ratio(samples.rssi1_dbm[mask], samples.rssi2_dbm[mask], table.k_d, cal.mode)
            ax.scatter(samples.angle_deg[mask], psi_s, s=4, alpha=0.25, label=f"samples ({label})")
        ax.plot(table.grid_deg, table.psi, lw=2, label=f"ψ_D ({label})")
        ax.axvspan(*table.fov_deg, color="tab:green", alpha=0.07)
    ax.axvline(0.0, color="grey", lw=0.8)
    ax.axhline(0.0, color="grey", lw=0.8)
    ax.set_xlabel("angle from boresight (degrees, clockwise)")
    ax.set_ylabel(f"monopulse ratio ψ ({cal.mode} mode)")
    ax.set_title("Monopulse calibration (shaded: unambiguous field of view)")
    ax.legend(loc="best", fontsize=8)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    try:
        save_figure(fig, path)
    finally:
        plt.close(fig)
