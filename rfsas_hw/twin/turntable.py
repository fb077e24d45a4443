"""Turntable calibration of a simulated sensor: what a bench run would give the real one.

The emitter stands at a fixed distance while the sensor turns through known
angles; the readings come from the same antenna pattern, chain imbalance,
measurement noise and quantisation that the twin uses in the field, and the
calibration is fitted with the real fitting code (:func:`rfsas_hw.df.fit_calibration`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from rfsas_hw.df.calibration import Calibration, fit_calibration
from rfsas_hw.df.monopulse import Mode
from rfsas_hw.rf.antenna import GaussianBeamPair
from rfsas_hw.rf.synth import ReceiverModel, turntable_sweep
from rfsas_hw.twin.rng import stream
from rfsas_hw.twin.scenario import Scenario, SensorSpec


def sensor_antenna(sensor: SensorSpec) -> GaussianBeamPair:
    """The beam model of a scenario sensor."""
    a = sensor.antenna
    return GaussianBeamPair(
        squint_deg=a.squint_deg,
        beamwidth_deg=a.beamwidth_deg,
        peak_gain_dbi=a.gain_dbi,
        front_to_back_db=a.front_to_back_db,
    )


def turntable_calibration(
    scenario: Scenario,
    sensor_id: str,
    *,
    mode: Mode = "linear",
    span_deg: float = 80.0,
    step_deg: float = 1.0,
    repeats: int = 30,
    peak_rx_dbm: float = -45.0,
    created: str = "2026-01-01T00:00:00Z",
) -> Calibration:
    """Calibrate one sensor of ``scenario`` on a simulated turntable.

    The sweep covers ``±span_deg`` in ``step_deg`` steps with ``repeats``
    frames per angle, on every channel of the sensor's scan plan, at a
    received power of ``peak_rx_dbm`` at the beam peak. Seeded from the
    scenario; ``created`` is fixed so that the file is reproducible.

    Raises:
        ConfigError: unknown sensor.
        CalibrationError: the fit fails (e.g. a field of view too narrow).
    """
    s = scenario.sensor(sensor_id)
    antenna = sensor_antenna(s)
    receiver = ReceiverModel(
        noise_floor_dbm=s.threshold_for("wifi"),
        measurement_floor_db=s.driver.measurement_floor_db,
        step_db=s.driver.step_db,
        chain_offsets_db=s.antenna.chain_offsets_db,
    )
    angles = np.arange(-span_deg, span_deg + 1e-9, step_deg)
    seed = int(stream(scenario.seed, "turntable", s.id).integers(0, 2**31))
    parts = [
        turntable_sweep(angles, repeats, peak_rx_dbm, antenna, receiver, seed + k, channel=ch)
        for k, ch in enumerate(s.scan.channels)
    ]
    samples = dataclasses.replace(
        parts[0],
        angle_deg=np.concatenate([p.angle_deg for p in parts]),
        rssi1_dbm=np.concatenate([p.rssi1_dbm for p in parts]),
        rssi2_dbm=np.concatenate([p.rssi2_dbm for p in parts]),
        channel=np.concatenate([p.channel for p in parts]),
    )
    cal = fit_calibration(
        samples,
        mode,
        step_db=s.driver.step_db,
        noise_floor_dbm=s.threshold_for("wifi"),
        antenna={
            "model": "gaussian-beam-pair (simulated turntable)",
            "squint_deg": s.antenna.squint_deg,
            "beamwidth_deg": s.antenna.beamwidth_deg,
            "sensor": s.id,
        },
    )
    return dataclasses.replace(cal, created=created)
