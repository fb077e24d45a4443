"""IQ reports an array's BLE receiver would give: an emulator writing HCI events.

For each packet: the CTE is an unmodulated tone, so every sample is
``A·e^{jψ}·a_k(θ)·e^{j2π·Δf·t}`` plus noise, with ``k`` the antenna the
switching pattern had on at sample time ``t`` (:func:`sample_times_us`),
``Δf`` the transmitter's carrier offset and ``A`` set so that a sample's
SNR is the one asked for. Samples are rounded to int8; one beyond ±127 is
written as the "no valid sample" sentinel, as a saturating controller does.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from rfsas_hw.df.array import ArrayGeometry
from rfsas_hw.sources.ble_iq import (
    BTSNOOP_EPOCH_OFFSET_US,
    BTSNOOP_MAGIC,
    REFERENCE_SAMPLES,
    IqReport,
    Kind,
    ble_channel_mhz,
    encode_iq_event,
    sample_times_us,
)


def iq_reports(
    geometry: ArrayGeometry,
    pattern: Sequence[int],
    theta_deg: npt.ArrayLike,
    snr_db: npt.ArrayLike,
    cfo_hz: npt.ArrayLike,
    rng: np.random.Generator,
    *,
    channel_index: int = 17,
    slot_us: int = 2,
    n_samples: int = 8 + 37,
    amplitude: float = 40.0,
    kind: Kind = "connectionless",
    handle: npt.ArrayLike = 1,
    rssi_dbm: npt.ArrayLike = -60.0,
    element_gain: npt.ArrayLike | None = None,
) -> list[IqReport]:
    """One report per angle in ``theta_deg`` (degrees clockwise from boresight).

    ``snr_db`` (per sample), ``cfo_hz``, ``handle`` and ``rssi_dbm`` are one value
    or one per report; ``element_gain`` (complex, one per antenna) is what each
    receive chain adds (its phase and gain errors; default none).

    Raises:
        ValueError: a pattern naming an antenna the array does not have.
    """
    if not pattern or min(pattern) < 0 or max(pattern) >= geometry.n:
        raise ValueError(f"switching pattern {list(pattern)} must name antennas 0…{geometry.n - 1}")
    theta = np.atleast_1d(np.asarray(theta_deg, np.float64))
    cfo = np.broadcast_to(np.asarray(cfo_hz, np.float64), theta.shape)
    snr = np.broadcast_to(np.asarray(snr_db, np.float64), theta.shape)
    handles = np.broadcast_to(np.asarray(handle, np.int64), theta.shape)
    rssi = np.broadcast_to(np.asarray(rssi_dbm, np.float64), theta.shape)
    freq = ble_channel_mhz(channel_index)
    t = sample_times_us(n_samples, slot_us) * 1e-6
    ant = np.array(
        [pattern[0]] * REFERENCE_SAMPLES
        + [pattern[(j + 1) % len(pattern)] for j in range(n_samples - REFERENCE_SAMPLES)]
    )
    noise_sigma = amplitude / np.sqrt(10.0 ** (snr / 10.0))
    steer = geometry.steering(theta, freq)  # (n, N)
    if element_gain is not None:
        steer = steer * np.broadcast_to(np.asarray(element_gain, np.complex128), (geometry.n,))
    out = []
    for i in range(len(theta)):
        phase0 = rng.uniform(0.0, 2.0 * math.pi)
        clean = amplitude * np.exp(1j * (phase0 + 2.0 * math.pi * cfo[i] * t)) * steer[i, ant]
        noise = rng.standard_normal(n_samples) + 1j * rng.standard_normal(n_samples)
        x = clean + noise * noise_sigma[i] / math.sqrt(2.0)
        q = np.round(x.real) + 1j * np.round(x.imag)
        q[(np.abs(q.real) > 127) | (np.abs(q.imag) > 127)] = np.nan
        out.append(
            IqReport(
                kind,
                int(handles[i]),
                channel_index,
                1,
                float(rssi[i]),
                pattern[0],
                0,
                slot_us,
                0,
                i % 65536,
                q,
            )
        )
    return out


def h4_stream(reports: Sequence[IqReport]) -> bytes:
    """The reports as an H4 (UART) byte stream of HCI event packets."""
    return b"".join(b"\x04" + encode_iq_event(r) for r in reports)


def btsnoop_file(
    reports: Sequence[IqReport],
    t0_ns: int,
    step_ns: int = 10_000_000,
    t_ns: Sequence[int] | None = None,
) -> bytes:
    """The reports as a btsnoop file (datalink 1002, H4): record ``i`` at ``t_ns[i]``
    (UTC ns) when given, else at ``t0_ns + i·step_ns``."""
    out = [BTSNOOP_MAGIC, struct.pack(">II", 1, 1002)]
    for i, r in enumerate(reports):
        packet = b"\x04" + encode_iq_event(r)
        at = t0_ns + i * step_ns if t_ns is None else int(t_ns[i])
        ts = at // 1000 + BTSNOOP_EPOCH_OFFSET_US
        out.append(struct.pack(">IIIIq", len(packet), len(packet), 0x03, 0, ts) + packet)
    return b"".join(out)
