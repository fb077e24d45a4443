"""Link budget and SNR for Wi-Fi and Bluetooth emitters (method.md §2).

``Pr = Pt + Gt + Gr − PL − margin`` (dBm) and ``SNR = Pr − threshold`` (dB).
The defaults reproduce the published table: Wi-Fi at 100 m gives
PL 93.802 dB, Pr −75.802 dBm and SNR 15.088 dB.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from rfsas_hw.errors import ConfigError
from rfsas_hw.rf.propagation import TABLE_OFFSET_DB, PathLossModel, path_loss_db

Radio = Literal["wifi", "bt"]
MAX_EIRP_DBM = 30.0


@dataclass(frozen=True, slots=True)
class RadioParams:
    """Transmitter, antennas and receiver of one link."""

    pt_dbm: float
    """Transmit power, dBm."""
    threshold_dbm: float
    """Receiver sensitivity threshold that SNR is measured against, dBm."""
    freq_mhz: float
    """Carrier frequency, MHz (used by the physical path-loss models)."""
    gt_dbi: float = 3.0
    """Transmit antenna gain, dBi."""
    gr_dbi: float = 3.0
    """Receive antenna gain, dBi."""
    margin_db: float = 15.0
    """Fade / implementation margin, dB."""
    ht_m: float = 1.0
    """Transmit antenna height, metres."""
    hr_m: float = 1.0
    """Receive antenna height, metres."""
    model: PathLossModel = "table"
    """Path-loss model: table (published), breakpoint or coherent two-ray."""
    offset_db: float = TABLE_OFFSET_DB
    """Constant of the table model, dB."""


RADIOS: dict[str, RadioParams] = {
    "wifi": RadioParams(pt_dbm=27.0, threshold_dbm=-90.89, freq_mhz=2437.0),
    "bt": RadioParams(pt_dbm=7.0, threshold_dbm=-103.9, freq_mhz=2440.0),
}


@dataclass(frozen=True, slots=True)
class LinkBudget:
    """Result of :func:`link_budget`; arrays when the distance was an array."""

    distance_m: Any
    """Distance, metres."""
    path_loss_db: Any
    """Path loss, dB."""
    rx_power_dbm: Any
    """Received power, dBm."""
    snr_db: Any
    """Received power above the threshold, dB."""
    params: RadioParams
    """The parameters used."""


def radio_params(radio: str = "wifi", **overrides: Any) -> RadioParams:
    """Default parameters of ``radio`` with ``overrides`` applied.

    Raises:
        ConfigError: unknown radio or parameter name, or EIRP above +30 dBm.
    """
    if radio not in RADIOS:
        raise ConfigError(f"unknown radio {radio!r}: use one of {', '.join(RADIOS)}")
    names = {f.name for f in dataclasses.fields(RadioParams)}
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise ConfigError(
            f"unknown link-budget parameter {unknown[0]!r} (known: {', '.join(sorted(names))})"
        )
    params = dataclasses.replace(RADIOS[radio], **overrides)
    eirp = params.pt_dbm + params.gt_dbi
    if eirp > MAX_EIRP_DBM + 1e-9:
        raise ConfigError(f"EIRP {eirp:.1f} dBm exceeds the +{MAX_EIRP_DBM:.0f} dBm limit")
    return params


def link_budget(distance_m: Any, radio: str = "wifi", **overrides: Any) -> LinkBudget:
    """Path loss, received power and SNR at ``distance_m`` metres (float or array).

    ``overrides`` replace any :class:`RadioParams` field, e.g. ``pt_dbm=20``.

    Raises:
        ConfigError: unknown radio or parameter, EIRP above +30 dBm.
        ValueError: a non-positive distance.
    """
    p = radio_params(radio, **overrides)
    pl = path_loss_db(
        distance_m if isinstance(distance_m, np.ndarray) else float(distance_m),
        p.model,
        freq_mhz=p.freq_mhz,
        ht_m=p.ht_m,
        hr_m=p.hr_m,
        offset_db=p.offset_db,
    )
    pr = p.pt_dbm + p.gt_dbi + p.gr_dbi - pl - p.margin_db
    return LinkBudget(distance_m, pl, pr, pr - p.threshold_dbm, p)
