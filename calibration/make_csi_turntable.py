"""Write a twin CSI turntable capture and its angle log, for trying ``rfsas calibrate --phase``.

    python calibration/make_csi_turntable.py OUTDIR

Writes ``OUTDIR/turntable.csi`` (FeitCSI layout: two antennas 6.15 cm apart,
channel 6, 56 subcarriers, 30 dB per subcarrier, a hardware phase offset of
40° and 0.3 ns of extra delay on antenna 1, the reference transmitter
02:00:00:00:00:42) and ``OUTDIR/angles.csv`` (−40°…+40° in 5° steps, 60
frames per step, 20 ms apart; times in the capture's clock). Then::

    rfsas calibrate calibration/example_cal.yaml --phase 'csi:OUTDIR/turntable.csi?freq=2437' \\
        --angles OUTDIR/angles.csv --emitter 02:00:00:00:00:42 --baseline 0.0615 \\
        -o OUTDIR/cal-phase.yaml
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from rfsas_hw.twin.csi_writer import CsiArray, synth_csi, write_feitcsi

ARRAY = CsiArray(baseline_m=0.0615, phase_offset_deg=40.0, delay_ns=0.3)
FRAMES_PER_STEP = 60


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    steps = np.arange(-40.0, 40.1, 5.0)
    theta = np.repeat(steps, FRAMES_PER_STEP)
    n = len(theta)
    h = synth_csi(ARRAY, theta, 2437, np.full((n, 2), 30.0), seed=1)
    t = np.arange(n, dtype=np.int64) * 20_000_000 + 1_000_000
    macs = np.full(n, 0x020000000042, np.uint64)
    write_feitcsi(out / "turntable.csi", t, macs, np.full((n, 2), -50.0), h)
    rows = ["t_ns,angle_deg"]
    for k, angle in enumerate(steps):
        dwell = t[k * FRAMES_PER_STEP : (k + 1) * FRAMES_PER_STEP]
        rows += [f"{dwell[0] - 1000},{angle}", f"{dwell[-1] + 1000},{angle}"]
    (out / "angles.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python calibration/make_csi_turntable.py OUTDIR")
    main(Path(sys.argv[1]))
