"""Regenerate the example turntable logs from the antenna model.

    python calibration/make_example.py

Writes ``example_turntable.csv`` (the fitting run: -90°…+90° in 1° steps,
20 frames per step) and ``example_turntable_check.csv`` (a held-back run at
angles between the fitting steps, 40 frames per step, another seed). The
model: two Gaussian beams squinted ±20° with 45° beamwidth and a 25 dB
front-to-back floor, -50 dBm at the beam peak, 1 dB RSSI spread, chain 1
1.5 dB weaker than chain 0 (what K_D balances), readings rounded to 1 dB.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rfsas_hw.df import write_samples_csv
from rfsas_hw.rf import GaussianBeamPair, ReceiverModel, turntable_sweep

HERE = Path(__file__).resolve().parent
ANTENNA = GaussianBeamPair(
    squint_deg=20.0, beamwidth_deg=45.0, peak_gain_dbi=3.0, front_to_back_db=25.0
)
RECEIVER = ReceiverModel(measurement_floor_db=1.0, step_db=1.0, chain_offsets_db=(0.0, -1.5))
PEAK_RX_DBM = -50.0
CHANNEL = 6


def main() -> None:
    fit = turntable_sweep(
        np.arange(-90.0, 90.5, 1.0), 20, PEAK_RX_DBM, ANTENNA, RECEIVER, 2026, CHANNEL
    )
    check = turntable_sweep(
        np.arange(-89.25, 90.0, 2.5), 40, PEAK_RX_DBM, ANTENNA, RECEIVER, 7, CHANNEL
    )
    write_samples_csv(HERE / "example_turntable.csv", fit)
    write_samples_csv(HERE / "example_turntable_check.csv", check)
    print(f"wrote {len(fit.angle_deg)} + {len(check.angle_deg)} samples to {HERE}")


if __name__ == "__main__":
    main()
