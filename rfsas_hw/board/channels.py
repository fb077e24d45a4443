"""IEEE channel numbers ↔ centre frequencies, as the board protocol uses them."""

from __future__ import annotations

from rfsas_hw.errors import ConfigError

BLE_ADV_MHZ = {37: 2402, 38: 2426, 39: 2480}
"""BLE advertising channels."""


def channel_to_freq_mhz(channel: int, *, ble: bool = False) -> int:
    """Centre frequency of a Wi-Fi channel (or a BLE advertising channel), MHz.

    Raises:
        ConfigError: not a 2.4/5 GHz Wi-Fi channel (or BLE channel 37–39).
    """
    if ble:
        if channel in BLE_ADV_MHZ:
            return BLE_ADV_MHZ[channel]
        raise ConfigError(f"{channel} is not a BLE advertising channel (37–39)")
    if 1 <= channel <= 13:
        return 2407 + 5 * channel
    if channel == 14:
        return 2484
    if 32 <= channel <= 177:
        return 5000 + 5 * channel
    raise ConfigError(f"{channel} is not a Wi-Fi channel (1–14, 32–177)")


def freq_to_channel(freq_mhz: int) -> int:
    """Wi-Fi channel number of a centre frequency (BLE advertising: 37–39), 0 if none."""
    for ch, f in BLE_ADV_MHZ.items():
        if freq_mhz == f:  # no Wi-Fi channel is centred on these
            return ch
    if freq_mhz == 2484:
        return 14
    if 2412 <= freq_mhz <= 2472 and (freq_mhz - 2407) % 5 == 0:
        return (freq_mhz - 2407) // 5
    if 5160 <= freq_mhz <= 5885 and freq_mhz % 5 == 0:
        return (freq_mhz - 5000) // 5
    return 0
