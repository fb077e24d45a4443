"""IEEE channel numbers ↔ centre frequencies for Wi-Fi and Bluetooth LE.

Wi-Fi: 2.4 GHz ``2407 + 5·n`` (channel 14 at 2484), 4.9 GHz (Japan)
``4000 + 5·n``, 5 GHz ``5000 + 5·n``, 6 GHz ``5950 + 5·n`` (channel 2 at 5935).
BLE: data channels 0–36 at ``2404 + 2·n`` (+2 MHz from channel 11 on, to skip
the advertising channel at 2426), advertising channels 37/38/39 at
2402/2426/2480 MHz — none of which is a Wi-Fi centre frequency.
"""

from __future__ import annotations

from typing import Literal, overload

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import ConfigError

Tech = Literal["wifi", "ble"]
BLE_ADV_MHZ = {37: 2402, 38: 2426, 39: 2480}
"""BLE advertising channels and their centre frequencies, MHz."""


def channel_to_freq_mhz(channel: int, tech: str = "wifi") -> int:
    """Centre frequency of a Wi-Fi channel (1–14, 32–177) or a BLE channel (0–39), MHz.

    Raises:
        ConfigError: not a channel of that technology.
    """
    if tech in ("ble", "bt"):
        if channel in BLE_ADV_MHZ:
            return BLE_ADV_MHZ[channel]
        if 0 <= channel <= 36:
            return 2404 + 2 * channel + (2 if channel >= 11 else 0)
        raise ConfigError(f"{channel} is not a BLE channel (0–39)")
    if tech != "wifi":
        raise ConfigError(f"unknown radio technology {tech!r}: use wifi or ble")
    if 1 <= channel <= 13:
        return 2407 + 5 * channel
    if channel == 14:
        return 2484
    if 32 <= channel <= 177:
        return 5000 + 5 * channel
    raise ConfigError(f"{channel} is not a Wi-Fi channel (1–14, 32–177)")


def _channel(f: int) -> int:
    for ch, adv in BLE_ADV_MHZ.items():
        if f == adv:
            return ch
    if 2412 <= f <= 2472 and (f - 2407) % 5 == 0:
        return (f - 2407) // 5
    if f == 2484:
        return 14
    if 4910 <= f <= 4980:
        return (f - 4000) // 5
    if 5000 <= f <= 5925:
        return (f - 5000) // 5
    if f == 5935:
        return 2
    if 5950 < f <= 7125:
        return (f - 5950) // 5
    return 0


_MAX_FREQ = 7200
_CHANNEL = np.array([_channel(f) for f in range(_MAX_FREQ)], np.int16)


@overload
def freq_to_channel(freq_mhz: int) -> int: ...
@overload
def freq_to_channel(freq_mhz: npt.NDArray[np.integer]) -> npt.NDArray[np.int16]: ...
def freq_to_channel(freq_mhz: int | npt.NDArray[np.integer]) -> int | npt.NDArray[np.int16]:
    """Channel number of centre frequencies in MHz (0 where none); scalar or array."""
    f = np.asarray(freq_mhz, np.int64)
    out: npt.NDArray[np.int16] = np.where(
        (f >= 0) & (f < _MAX_FREQ), _CHANNEL[np.clip(f, 0, _MAX_FREQ - 1)], 0
    ).astype(np.int16)
    return out if isinstance(freq_mhz, np.ndarray) else int(out)
