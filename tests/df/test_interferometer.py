"""Phase interferometer: sign and geometry, σ against the CRB, branches, FoV, calibration.

Channels come from :func:`rfsas_hw.twin.csi_writer.synth_csi` (plane wave,
unit-power complex noise per subcarrier, random common phase and STO slope,
a hardware offset and chain delay on antenna 1). Monte Carlo tolerances:
with N frames the RMS is known to about 1/√(2N) (N = 3000: 1.3 %).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from rfsas_hw.df import load_calibration, save_calibration
from rfsas_hw.df.calibration import Calibration, CalibrationTable
from rfsas_hw.df.hybrid import estimate_phase
from rfsas_hw.df.interferometer import (
    C_MPS,
    IfFlag,
    bearings,
    effective_snr_db,
    pair_phase,
    remove_sto,
)
from rfsas_hw.df.phasecal import (
    PhaseCalibration,
    PhaseOffset,
    PhasePair,
    fit_phase_offset,
    phase_from_mapping,
)
from rfsas_hw.errors import CalibrationError
from rfsas_hw.records import CsiBlock, ObservationBatch
from rfsas_hw.rf.aoa import sigma_phase_deg
from rfsas_hw.twin.csi_writer import CsiArray, synth_csi

FREQ = 2437.0
LAM = C_MPS / (FREQ * 1e6)


def _block(array: CsiArray, theta: np.ndarray, snr_db: float, seed: int) -> CsiBlock:
    h = synth_csi(array, theta, FREQ, np.full((len(theta), 2), snr_db), seed)
    return CsiBlock(h.astype(np.complex64), array.subcarriers())


def _crb_deg(theta: np.ndarray, d_over_lam: float, snr_eff_db: np.ndarray) -> np.ndarray:
    return np.degrees(
        1.0
        / (2 * math.pi * d_over_lam * np.cos(np.radians(theta)) * np.sqrt(10 ** (snr_eff_db / 10)))
    )


def test_sign_convention_clockwise_is_positive_phase() -> None:
    """A wave from +30° (clockwise) leads on antenna 1 by π·sin 30° = 90° at D = λ/2."""
    array = CsiArray(baseline_m=LAM / 2, sto_max=0.0)
    block = _block(array, np.array([30.0]), 80.0, seed=1)
    phase = pair_phase(block)
    assert math.degrees(phase.phase_rad[0]) == pytest.approx(90.0, abs=0.5)
    out = bearings(phase, FREQ, LAM / 2)
    assert out.angle_deg[0] == pytest.approx(30.0, abs=0.3)


def test_sto_removal_flattens_each_antenna() -> None:
    array = CsiArray(baseline_m=LAM / 2, sto_max=0.3)
    block = _block(array, np.zeros(50), 60.0, seed=2)
    flat = remove_sto(block.h, block.subcarrier)
    slope_before = np.angle(np.sum(block.h[:, 0, 0, 1:] * np.conj(block.h[:, 0, 0, :-1]), axis=1))
    slope_after = np.angle(np.sum(flat[:, 0, 0, 1:] * np.conj(flat[:, 0, 0, :-1]), axis=1))
    assert np.max(np.abs(slope_before)) > 0.1
    assert np.max(np.abs(slope_after)) < 0.01
    # the pair product is untouched by it
    np.testing.assert_allclose(
        flat[:, 1] * np.conj(flat[:, 0]),
        block.h[:, 1] * np.conj(block.h[:, 0]),
        rtol=1e-3,
        atol=1e-2,
    )


@pytest.mark.parametrize("snr_db", [20.0, 30.0])
def test_rms_within_crb_and_sigma_honest_half_wavelength(snr_db: float) -> None:
    array = CsiArray(baseline_m=LAM / 2, phase_offset_deg=40.0, delay_ns=0.5)
    turn = np.repeat(np.linspace(-40, 40, 17), 30)
    cal = fit_phase_offset(_block(array, turn, 30.0, seed=3), turn, FREQ, array.baseline_m)
    assert cal.offset_deg == pytest.approx(40.0, abs=0.2)
    assert cal.delay_ns == pytest.approx(0.5, abs=0.1)
    theta = np.random.default_rng(4).uniform(-20, 20, 3000)
    block = _block(array, theta, snr_db, seed=5)
    phase = pair_phase(block, offset_rad=math.radians(cal.offset_deg), delay_ns=cal.delay_ns)
    snr = effective_snr_db(snr_db, snr_db, phase.terms)
    out = bearings(phase, FREQ, array.baseline_m, snr_db=snr, residual_deg=cal.residual_deg)
    assert out.valid.all()
    rms = float(np.sqrt(np.mean((out.angle_deg - theta) ** 2)))
    crb = float(np.sqrt(np.mean(_crb_deg(theta, 0.5, snr) ** 2)))
    assert 0.95 <= rms / crb <= 1.2
    sigma = float(np.sqrt(np.mean(out.sigma_deg**2)))
    assert 0.85 <= rms / sigma <= 1.15


def test_sigma_is_the_method_formula_when_noise_dominates() -> None:
    block = _block(CsiArray(baseline_m=LAM / 2, sto_max=0.0), np.array([20.0]), 90.0, seed=6)
    phase = pair_phase(block)
    for form in ("textbook", "published"):
        out = bearings(phase, FREQ, LAM / 2, snr_db=27.0, form=form)  # type: ignore[arg-type]
        expect = sigma_phase_deg(
            27.0,
            out.angle_deg[0],
            baseline_m=LAM / 2,
            wavelength_m=LAM,
            form=form,  # type: ignore[arg-type]
        )
        assert out.sigma_deg[0] == pytest.approx(expect, rel=1e-6)


def test_two_wavelengths_is_ambiguous_alone_and_resolved_by_monopulse() -> None:
    array = CsiArray(baseline_m=2 * LAM)
    rng = np.random.default_rng(7)
    theta = rng.uniform(-40, 40, 2000)
    block = _block(array, theta, 20.0, seed=8)
    phase = pair_phase(block)
    alone = bearings(phase, FREQ, array.baseline_m, fov_deg=(-60, 60))
    assert np.all(alone.flags & IfFlag.AMBIGUOUS)
    assert np.all(alone.candidates >= 3)
    mono_sigma = 2.0  # a monopulse at 20 dB
    hint = theta + rng.normal(0, mono_sigma, len(theta))
    out = bearings(
        phase,
        FREQ,
        array.baseline_m,
        snr_db=effective_snr_db(20.0, 20.0, phase.terms),
        fov_deg=(-60, 60),
        hint_deg=hint,
        hint_sigma_deg=np.full(len(theta), mono_sigma),
    )
    right = out.valid & (np.abs(out.angle_deg - theta) < 2.0)
    assert right.mean() >= 0.99
    # a wrong branch never passes as valid
    assert not np.any(out.valid & (np.abs(out.angle_deg - theta) > 5.0))


def test_field_of_view_and_missing_chain() -> None:
    array = CsiArray(baseline_m=LAM / 2)
    block = _block(array, np.array([70.0, 10.0]), 40.0, seed=9)
    block.h[1, 1] = np.nan
    out = bearings(pair_phase(block), FREQ, array.baseline_m, fov_deg=(-60, 60))
    assert out.flags[0] & IfFlag.OUTSIDE_FOV
    assert out.flags[1] & IfFlag.MISSING_CHAIN
    assert not out.valid.any() and np.isnan(out.angle_deg).all()
    no_freq = bearings(pair_phase(_block(array, np.zeros(1), 40.0, 1)), 0.0, array.baseline_m)
    assert no_freq.flags[0] & IfFlag.NO_TABLE


def _amplitude_table() -> CalibrationTable:
    grid = np.linspace(-60, 60, 121)
    return CalibrationTable(None, 1.0, grid, grid / 70.0, (-60.0, 60.0), 0.1)


def test_phase_section_round_trips_through_the_calibration_file(tmp_path: Path) -> None:
    phase = PhaseCalibration(
        (
            PhasePair(
                0, 1, 0.0615, (PhaseOffset(6, 41.25, 0.12, 3.5, 900), PhaseOffset(None, 40.0))
            ),
        ),
        (-50.0, 55.0),
    )
    cal = Calibration("linear", (_amplitude_table(),), phase=phase)
    path = tmp_path / "cal.yaml"
    save_calibration(cal, path)
    back = load_calibration(path)
    assert back.phase == phase
    assert back.phase is not None and back.phase.pairs[0].offset_for(11) == PhaseOffset(None, 40.0)
    plain = tmp_path / "plain.yaml"
    save_calibration(Calibration("linear", (_amplitude_table(),)), plain)
    assert "phase" not in plain.read_text() and load_calibration(plain).phase is None


@pytest.mark.parametrize(
    ("section", "match"),
    [
        ({"pairs": []}, r"phase\.pairs: expected a non-empty list"),
        (
            {"pairs": [{"a": 0, "b": 0, "baseline_m": 0.06, "offsets": [{"offset_deg": 1}]}]},
            "two different",
        ),
        (
            {"pairs": [{"a": 0, "b": 1, "baseline_m": -1, "offsets": [{"offset_deg": 1}]}]},
            "baseline_m: must be positive",
        ),
        (
            {"pairs": [{"a": 0, "b": 1, "baseline_m": 0.06, "offsets": [{"offset": 1}]}]},
            r"offsets\[0\]: unknown key",
        ),
        ({"fov_deg": [10, -10], "pairs": []}, "fov_deg"),
        (
            {"pairs": [{"a": 0, "b": 1, "baseline_m": 10**400, "offsets": [{"offset_deg": 1}]}]},
            "baseline_m: must be a finite number",
        ),
        (
            {"pairs": [{"a": 0, "b": 1, "baseline_m": 0.06, "offsets": [{"offset_deg": "x"}]}]},
            "offset_deg: must be a finite number",
        ),
    ],
)
def test_bad_phase_sections_name_the_key(section: dict[str, object], match: str) -> None:
    with pytest.raises(CalibrationError, match=match):
        phase_from_mapping(section, "cal.yaml: phase")


def test_calibration_needs_enough_frames() -> None:
    array = CsiArray(baseline_m=LAM / 2)
    with pytest.raises(CalibrationError, match="need at least"):
        fit_phase_offset(_block(array, np.zeros(3), 30.0, 1), np.zeros(3), FREQ, LAM / 2)


def test_hybrid_estimate_from_observations() -> None:
    """Observations with RSSI and CSI: the monopulse table picks the branch of a 2λ pair."""
    array = CsiArray(baseline_m=2 * LAM, phase_offset_deg=-70.0)
    rng = np.random.default_rng(11)
    theta = rng.uniform(-30, 30, 500)
    block = _block(array, theta, 25.0, seed=12)
    # RSSI whose linear-mode monopulse table maps (r1 − r2)/… to θ: use the table's own curve
    table = _amplitude_table()
    psi = theta / 70.0 + rng.normal(0, 0.02, len(theta))
    # linear ratio ψ = (p1 − p2)/(p1 + p2) with K_D = 1 → p1/p2 = (1 + ψ)/(1 − ψ)
    diff_db = 10 * np.log10((1 + psi) / (1 - psi))
    rssi = np.column_stack([-60 + diff_db / 2, -60 - diff_db / 2]).astype(np.float32)
    batch = ObservationBatch(
        t_ns=np.arange(len(theta)),
        mac=np.full(len(theta), 0x020000000001),
        freq_mhz=np.full(len(theta), 2437),
        channel=np.full(len(theta), 6),
        rssi_dbm=rssi,
        csi=block,
    )
    phase = PhaseCalibration((PhasePair(0, 1, array.baseline_m, (PhaseOffset(6, -70.0),)),))
    cal = Calibration("linear", (table,), step_db=0.01, noise_floor_dbm=-85.0, phase=phase)
    out, snr = estimate_phase(cal, batch)
    assert np.all(np.isfinite(snr))
    good = out.valid & (np.abs(out.angle_deg - theta) < 1.0)
    assert good.mean() >= 0.99
    with pytest.raises(CalibrationError, match="no phase section"):
        estimate_phase(Calibration("linear", (table,)), batch)
    other = ObservationBatch(
        t_ns=batch.t_ns,
        mac=batch.mac,
        freq_mhz=batch.freq_mhz,
        channel=np.full(len(theta), 11),
        rssi_dbm=rssi,
        csi=block,
    )
    assert np.all(estimate_phase(cal, other)[0].flags & IfFlag.NO_TABLE)


def test_5300_phase_ambiguity_withholds_the_bearing() -> None:
    from rfsas_hw.records import ObsFlag

    array = CsiArray(baseline_m=LAM / 2)
    theta = np.array([5.0, 10.0])
    block = _block(array, theta, 30.0, seed=13)
    batch = ObservationBatch(
        t_ns=np.arange(2),
        mac=np.zeros(2),
        freq_mhz=np.full(2, 2437),
        channel=np.full(2, 6),
        rssi_dbm=np.full((2, 2), -50.0),
        flags=np.array([0, ObsFlag.PHASE_AMBIGUOUS]),
        csi=block,
    )
    phase = PhaseCalibration((PhasePair(0, 1, LAM / 2, (PhaseOffset(None, 0.0),)),))
    cal = Calibration("linear", (_amplitude_table(),), phase=phase)
    out, _ = estimate_phase(cal, batch, hybrid=False)
    assert out.valid.tolist() == [True, False]
    assert out.flags[1] & IfFlag.AMBIGUOUS
