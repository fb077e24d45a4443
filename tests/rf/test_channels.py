"""Channel ↔ frequency for Wi-Fi and BLE, one table for every package."""

from __future__ import annotations

import numpy as np
import pytest

from rfsas_hw.errors import ConfigError
from rfsas_hw.rf.channels import channel_to_freq_mhz, freq_to_channel

KNOWN = [
    (1, "wifi", 2412),
    (6, "wifi", 2437),
    (14, "wifi", 2484),
    (36, "wifi", 5180),
    (165, "wifi", 5825),
    (37, "ble", 2402),
    (38, "ble", 2426),
    (39, "ble", 2480),
    (0, "ble", 2404),
    (11, "ble", 2428),
]


@pytest.mark.parametrize(("channel", "tech", "freq"), KNOWN)
def test_known_channels(channel: int, tech: str, freq: int) -> None:
    assert channel_to_freq_mhz(channel, tech) == freq
    # frequencies map back for Wi-Fi and BLE advertising; BLE data channels overlap Wi-Fi
    expected = channel if tech == "wifi" or channel >= 37 else 0
    assert freq_to_channel(freq) == expected


def test_round_trip_over_every_wifi_channel() -> None:
    wifi = [*range(1, 15), *range(32, 178)]
    freqs = np.array([channel_to_freq_mhz(c) for c in wifi])
    assert freq_to_channel(freqs).tolist() == wifi


def test_unknown_inputs() -> None:
    assert freq_to_channel(2413) == 0 and freq_to_channel(-5) == 0 and freq_to_channel(99_999) == 0
    with pytest.raises(ConfigError, match="not a Wi-Fi channel"):
        channel_to_freq_mhz(15)
    with pytest.raises(ConfigError, match="not a BLE channel"):
        channel_to_freq_mhz(40, "ble")
