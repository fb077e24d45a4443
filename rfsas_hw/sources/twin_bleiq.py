"""BLE IQ reports from the twin: an antenna array at a sensor's pose, written as btsnoop.

The twin's sensors hear frames through their two-beam antenna
(:class:`~rfsas_hw.twin.world.Receptions`). A BLE direction-finding array at
the same pose hears each of those frames as a packet with a Constant Tone
Extension: its IQ report (:func:`~rfsas_hw.sources.ble_iq_emulator.iq_reports`)
has the frame's true angle from boresight, the frame's true SNR with the
beam pair's gains taken out (the array's elements are omnidirectional; the
mean of the two chains), a carrier offset fixed per emitter (drawn in
±``max_cfo_hz``), the array's chain phase and gain errors, and the frame's
time. Reports carry the emitter's sync handle (emitter index + 1), as HCI
IQ reports carry no address. Seeded: the same inputs give the same bytes.

Which frames: every frame the sensor hears (the twin's emitters stand for
CTE transmitters; Wi-Fi frames too, unless ``only_ble``). Frames the
two-beam receiver does not hear (far behind it, below its threshold) are
not written: the array hears a subset of what it could.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from rfsas_hw.df.array import C_MPS, ArrayGeometry
from rfsas_hw.errors import SimulationError
from rfsas_hw.sources.ble_iq import MAX_SAMPLES, REFERENCE_SAMPLES, ble_channel_mhz
from rfsas_hw.sources.ble_iq_emulator import btsnoop_file, iq_reports
from rfsas_hw.twin.world import TECH_CODES, World

BLE_TECH = TECH_CODES["ble"]


@dataclass(frozen=True, slots=True)
class BleArray:
    """The twin's BLE direction-finding array."""

    geometry: ArrayGeometry
    """Element positions (the array's boresight is the sensor's heading)."""
    channel_index: int = 17
    """BLE channel the CTEs are sampled on."""
    slot_us: int = 2
    """Switch and sample slot, µs."""
    cte_us: int = 160
    """CTE length, µs (guard 4 and reference 8 included)."""
    max_cfo_hz: float = 150_000.0
    """Emitters' carrier offsets are drawn in ± this, Hz."""
    chain_phase_deg: tuple[float, ...] | None = None
    """What each receive chain adds to the phase, degrees (None: nothing)."""
    chain_gain_db: tuple[float, ...] | None = None
    """What each receive chain adds to the gain, dB (None: nothing)."""

    @classmethod
    def uca(cls, n: int, radius_wavelengths: float, channel_index: int = 17) -> BleArray:
        """An ``n``-element circular array of the given radius in wavelengths."""
        lam = C_MPS / (ble_channel_mhz(channel_index) * 1e6)
        return cls(ArrayGeometry.uca(n, radius_wavelengths * lam), channel_index)

    def chains(self) -> npt.NDArray[np.complex128]:
        """Complex gain of each receive chain."""
        n = self.geometry.n
        phase = np.radians(np.asarray(self.chain_phase_deg or [0.0] * n, np.float64))
        gain = np.asarray(self.chain_gain_db or [0.0] * n, np.float64)
        if len(phase) != n or len(gain) != n:
            raise SimulationError(f"chain errors need {n} values, one per element")
        return np.asarray(np.exp(1j * phase) * 10.0 ** (gain / 20.0), np.complex128)


def write_sensor_bleiq(
    world: World,
    sensor_id: str,
    array: BleArray,
    path: str | Path,
    seed: int,
    *,
    only_ble: bool = False,
) -> npt.NDArray[np.intp]:
    """Write the IQ reports an array at sensor ``sensor_id`` would give, as btsnoop;
    returns the rows of the sensor's receptions that were written (same order).

    Raises:
        ConfigError: no such sensor.
        SimulationError: chain errors of the wrong length, or a slot that is not 1 or 2.
    """
    if array.slot_us not in (1, 2):
        raise SimulationError(f"slot {array.slot_us} µs: 1 or 2 expected")
    rec = world.receptions(sensor_id)
    heard = rec.heard.any(axis=1)
    if only_ble:
        heard &= rec.tech == BLE_TECH
    rows = np.flatnonzero(heard)
    theta = rec.true_relative_deg[rows]
    gains = world.antennas[sensor_id].gains_db(theta)
    snr = np.mean(rec.snr_db[rows] - gains, axis=1)
    rng = np.random.default_rng(seed)
    n_emitters = len(world.scenario.spec.emitters)
    cfo = rng.uniform(-array.max_cfo_hz, array.max_cfo_hz, n_emitters)[rec.emitter[rows]]
    n_samples = min(MAX_SAMPLES, REFERENCE_SAMPLES + (array.cte_us - 12) // (2 * array.slot_us))
    reports = iq_reports(
        array.geometry,
        list(range(array.geometry.n)),
        theta,
        snr,
        cfo,
        rng,
        channel_index=array.channel_index,
        slot_us=array.slot_us,
        n_samples=n_samples,
        handle=rec.emitter[rows] + 1,
        rssi_dbm=np.nanmax(
            np.where(np.isfinite(rec.chain_dbm[rows]), rec.chain_dbm[rows], -127.0), 1
        ),
        element_gain=array.chains(),
    )
    data = btsnoop_file(reports, 0, t_ns=rec.t_ns[rows].tolist())
    Path(path).write_bytes(data)
    return rows
