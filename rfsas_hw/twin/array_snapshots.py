"""Complex samples an antenna array would take of plane waves: the twin's array receiver.

Each packet is ``S`` snapshots of ``x = c·g⊙a(θ) + Σ_m c_m·g⊙a(θ_m) + n``:
one direct wave with a random phase per snapshot, optional reflections at
other angles (multipath: coherent with the direct wave, fixed relative
amplitude and phase), each chain's phase and gain ``g`` (what element
calibration removes), and circular white Gaussian noise at the given SNR per
element and snapshot. Seeded and vectorised.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from rfsas_hw.df.array import ArrayGeometry


def array_snapshots(
    geometry: ArrayGeometry,
    theta_deg: npt.ArrayLike,
    snr_db: npt.ArrayLike,
    freq_mhz: float,
    rng: np.random.Generator,
    *,
    snapshots: int = 1,
    chain_phase_rad: npt.ArrayLike | None = None,
    chain_gain_db: npt.ArrayLike | None = None,
    reflections: Sequence[tuple[float, float, float]] = (),
) -> npt.NDArray[np.complex128]:
    """Samples of shape (packets, snapshots, N) for emitters at ``theta_deg`` (packets,).

    Args:
        geometry: the array.
        theta_deg: direct-path azimuth per packet, degrees clockwise from boresight.
        snr_db: direct-path SNR per element and snapshot, dB (one or per packet).
        freq_mhz: carrier, MHz.
        rng: the random stream.
        snapshots: snapshots per packet.
        chain_phase_rad, chain_gain_db: what each receive chain adds (None: nothing).
        reflections: ``(offset_deg, relative_db, phase_rad)`` of each reflected wave,
            its azimuth the direct one's plus ``offset_deg``.
    """
    theta = np.atleast_1d(np.asarray(theta_deg, np.float64))
    n, n_el = len(theta), geometry.n
    snr = np.broadcast_to(np.asarray(snr_db, np.float64), (n,))
    amp = 10.0 ** (snr / 20.0)
    steer = geometry.steering(theta, freq_mhz)
    for offset, rel_db, phase in reflections:
        w = 10.0 ** (rel_db / 20.0) * np.exp(1j * phase)
        steer = steer + w * geometry.steering(theta + offset, freq_mhz)
    chain = np.ones(n_el, np.complex128)
    if chain_phase_rad is not None:
        chain = chain * np.exp(1j * np.asarray(chain_phase_rad, np.float64))
    if chain_gain_db is not None:
        chain = chain * 10.0 ** (np.asarray(chain_gain_db, np.float64) / 20.0)
    c = amp[:, None] * np.exp(2j * np.pi * rng.random((n, snapshots)))
    noise = rng.standard_normal((n, snapshots, n_el)) + 1j * rng.standard_normal(
        (n, snapshots, n_el)
    )
    out: npt.NDArray[np.complex128] = c[:, :, None] * (steer * chain)[:, None, :] + noise / np.sqrt(
        2.0
    )
    return out
