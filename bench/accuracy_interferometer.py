"""Interferometer accuracy in the twin against the Cramér–Rao bound (part of bench_accuracy.py).

    python bench/bench_accuracy.py        (or: python bench/accuracy_interferometer.py)

A roadside sensor of two squinted beams (squint 15°, beamwidth 30°) whose
two antennas also give CSI (56 subcarriers, channel 6) hears 41 beaconing
emitters over ±20° of boresight at the distance that gives the target SNR at
the beam peak. The twin writes the frames as a FeitCSI capture (per-antenna
phase from the geometry, a hardware phase offset of 40° and 0.3 ns of chain
delay on antenna 1); the capture is read back through the ``csi:`` source.
The phase calibration is fitted on a simulated turntable (±40°, 30 frames
per degree step of 5°, 30 dB) and stored with the amplitude tables; bearings
come from :func:`rfsas_hw.df.hybrid.estimate_phase`.

Per frame the bound is ``1/(2π·(D/λ)·cos θ·√(N·SNR_pair))`` with the true
per-chain SNRs (``SNR_pair = 2/(1/SNR_1 + 1/SNR_2)``, N subcarriers).
Side by side: the amplitude monopulse on the same frames (what the sensor
does without CSI) and the method's published σ formula. For D = 2λ the
branch chosen by the monopulse is compared with the true one.
Goals: RMS ≤ 1.2 × CRB at SNR ≥ 20 dB for D = λ/2; the right branch in
≥ 99 % of frames at SNR ≥ 20 dB for D = 2λ.
"""

from __future__ import annotations

import dataclasses
import math
import tempfile
from pathlib import Path

import numpy as np

from rfsas_hw.angles import wrap_deg_180
from rfsas_hw.df.estimate import estimate
from rfsas_hw.df.hybrid import estimate_phase
from rfsas_hw.df.interferometer import C_MPS
from rfsas_hw.df.phasecal import PhaseCalibration, PhasePair, fit_phase_offset
from rfsas_hw.records import CsiBlock
from rfsas_hw.rf.aoa import sigma_phase_deg
from rfsas_hw.rf.propagation import TABLE_OFFSET_DB
from rfsas_hw.sources.csi import capture_frames
from rfsas_hw.twin.csi_writer import CsiArray, synth_csi, write_sensor_csi
from rfsas_hw.twin.scenario import scenario_from_mapping
from rfsas_hw.twin.turntable import turntable_calibration
from rfsas_hw.twin.world import World

SQUINT, BEAMWIDTH, FLOOR_DB = 15.0, 30.0, 0.7
TX_DBM, THRESHOLD = 20.0, -90.89
FREQ_MHZ = 2437
LAM = C_MPS / (FREQ_MHZ * 1e6)
GOAL_RMS, GOAL_RESOLVED = 1.2, 0.99


def _scenario(snr_db: float, duration_s: float) -> object:
    pl = TX_DBM + 3.0 + 3.0 - 15.0 - THRESHOLD - snr_db
    d = float(10 ** ((pl - TABLE_OFFSET_DB) / 40.0))
    angles = np.linspace(-20, 20, 41)
    return scenario_from_mapping(
        {
            "version": 1,
            "name": f"csi-{snr_db:g}",
            "seed": 21,
            "duration_s": duration_s,
            "emitters": [
                {
                    "id": f"e{i}",
                    "mac": f"02:00:00:00:{i // 256:02x}:{i % 256:02x}",
                    "tech": "wifi",
                    "tx_power_dbm": TX_DBM,
                    "position": [d * math.sin(math.radians(a)), d * math.cos(math.radians(a))],
                    "traffic": [{"model": "beacon", "channels": [6]}],
                }
                for i, a in enumerate(angles)
            ],
            "sensors": [
                {
                    "id": "s",
                    "kind": "roadside",
                    "pose": {"x_m": 0.0, "y_m": 0.0, "heading_deg": 0.0},
                    "antenna": {"squint_deg": SQUINT, "beamwidth_deg": BEAMWIDTH},
                    "driver": {"measurement_floor_db": FLOOR_DB},
                }
            ],
        },
        "<bench>",
    )


def phase_turntable(array: CsiArray, seed: int = 5) -> PhasePair:
    """The pair's calibration from a simulated turntable sweep."""
    turn = np.repeat(np.arange(-40.0, 40.1, 5.0), 30)
    h = synth_csi(array, turn, FREQ_MHZ, np.full((len(turn), 2), 30.0), seed)
    block = CsiBlock(h.astype(np.complex64), array.subcarriers())
    offset = fit_phase_offset(block, turn, FREQ_MHZ, array.baseline_m, channel=6)
    return PhasePair(0, 1, array.baseline_m, (offset,))


def interferometer_at(
    snr_db: float, d_over_lambda: float, duration_s: float = 10.0
) -> dict[str, float]:
    """One SNR and baseline: RMS, CRB, σ, monopulse RMS, branch resolution."""
    array = CsiArray(baseline_m=d_over_lambda * LAM, phase_offset_deg=40.0, delay_ns=0.3)
    sc = _scenario(snr_db, duration_s)
    world = World(sc)  # type: ignore[arg-type]
    rec = world.receptions("s")
    amplitude = turntable_calibration(sc, "s")  # type: ignore[arg-type]
    cal = dataclasses.replace(
        amplitude, phase=PhaseCalibration((phase_turntable(array),), (-60.0, 60.0))
    )
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "twin.csi"
        rows = write_sensor_csi(rec, array, path, seed=int(snr_db * 10 + d_over_lambda * 1000))
        batch = capture_frames(path, freq_mhz=FREQ_MHZ)
    truth = rec.true_relative_deg[rows]
    batch.channel[:] = 6
    res, _ = estimate_phase(cal, batch)
    ok = res.valid
    err = wrap_deg_180(res.angle_deg - truth)
    snr_true = rec.snr_db[rows]
    lin = np.power(10.0, snr_true / 10.0)
    pair = 2.0 / (1.0 / lin[:, 0] + 1.0 / lin[:, 1])
    n_sc = array.n_subcarriers
    crb = np.degrees(
        1.0 / (2 * math.pi * d_over_lambda * np.cos(np.radians(truth)) * np.sqrt(n_sc * pair))
    )
    mono = estimate(amplitude, batch.rssi_dbm[:, 0], batch.rssi_dbm[:, 1], batch.channel)
    mono_err = wrap_deg_180(mono.angle_deg[mono.valid] - truth[mono.valid])
    # the right branch: within a quarter of the branch spacing of the truth
    spacing = np.degrees(np.arcsin(min(1.0, 1.0 / d_over_lambda)))
    resolved = ok & (np.abs(err) < spacing / 4)
    return {
        "frames": float(len(truth)),
        "valid": float(ok.mean()),
        "rms": float(np.sqrt(np.mean(err[ok] ** 2))) if ok.any() else math.nan,
        "crb": float(np.sqrt(np.mean(crb[ok] ** 2))) if ok.any() else math.nan,
        "sigma": float(np.sqrt(np.mean(res.sigma_deg[ok] ** 2))) if ok.any() else math.nan,
        "mono_rms": float(np.sqrt(np.mean(mono_err**2))),
        "published": float(
            sigma_phase_deg(snr_db, baseline_m=d_over_lambda * LAM, wavelength_m=LAM)
        ),
        "resolved": float(resolved.mean()),
    }


def print_interferometer() -> None:
    """The interferometer table and the two goals."""
    print()
    print(
        "Interferometer (CSI, 56 subcarriers, channel 6) vs its CRB, twin at high detail; "
        "monopulse on the same frames beside it"
    )
    for d in (0.5, 2.0):
        print()
        print(f"D = {d:g} λ ({d * LAM * 100:.1f} cm)")
        print(
            f"{'SNR dB':>6} {'frames':>7} {'valid':>6} {'CRB °':>7} {'RMS °':>7} {'÷CRB':>6} "
            f"{'reported σ °':>13} {'right branch':>13} {'monopulse RMS °':>16} "
            f"{'published σ °':>14}"
        )
        worst_rms, worst_resolved = 0.0, 1.0
        for snr in (10, 15, 20, 25, 30, 40):
            r = interferometer_at(float(snr), d)
            ratio = r["rms"] / r["crb"]
            if snr >= 20:
                worst_rms = max(worst_rms, ratio)
                worst_resolved = min(worst_resolved, r["resolved"])
            print(
                f"{snr:>6} {int(r['frames']):>7} {r['valid']:>6.1%} {r['crb']:>7.3f} "
                f"{r['rms']:>7.3f} {ratio:>6.3f} {r['sigma']:>13.3f} {r['resolved']:>13.2%} "
                f"{r['mono_rms']:>16.3f} {r['published']:>14.3f}"
            )
        if d <= 0.5:
            print(
                f"goal RMS ≤ {GOAL_RMS:g} × CRB at SNR ≥ 20 dB: "
                f"{'met' if worst_rms <= GOAL_RMS else 'NOT met'} (worst {worst_rms:.3f} ×)"
            )
        else:
            print(
                f"goal right branch in ≥ {GOAL_RESOLVED:.0%} of frames at SNR ≥ 20 dB: "
                f"{'met' if worst_resolved >= GOAL_RESOLVED else 'NOT met'} "
                f"(worst {worst_resolved:.2%})"
            )


if __name__ == "__main__":
    print_interferometer()
