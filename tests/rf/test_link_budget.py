"""The published link-budget table and angle-error values (method.md §2–§3)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rfsas_hw.errors import ConfigError
from rfsas_hw.rf import (
    TABLE_OFFSET_DB,
    link_budget,
    path_loss_db,
    sigma_monopulse_deg,
    sigma_phase_deg,
)

# (radio, distance m, Pr dBm, PL dB, SNR dB) as printed, 3 decimals.
PUBLISHED = [
    ("wifi", 100.0, -75.802, 93.802, 15.088),
    ("bt", 100.0, -95.802, 93.802, 8.098),
    ("wifi", 25.0, -51.72, 69.72, 39.17),
    ("bt", 25.0, -71.72, 69.72, 32.18),
]


@pytest.mark.parametrize(("radio", "d", "pr", "pl", "snr"), PUBLISHED)
def test_published_table_to_printed_precision(
    radio: str, d: float, pr: float, pl: float, snr: float
) -> None:
    b = link_budget(d, radio)
    # printed to 3 decimals: agree to half a unit in the last place
    assert b.rx_power_dbm == pytest.approx(pr, abs=5e-4)
    assert b.path_loss_db == pytest.approx(pl, abs=5e-4)
    assert b.snr_db == pytest.approx(snr, abs=5e-4)


def test_table_offset_is_ten_log_24() -> None:
    assert TABLE_OFFSET_DB == pytest.approx(10 * math.log10(24))
    assert path_loss_db(100.0) == pytest.approx(93.802, abs=5e-4)


def test_published_sigmas_at_27_db() -> None:
    assert sigma_phase_deg(27.0) == pytest.approx(1.2285, abs=5e-5)
    assert sigma_monopulse_deg(27.0) == pytest.approx(1.4503, abs=5e-5)


def test_textbook_phase_form_is_two_pi_smaller() -> None:
    assert sigma_phase_deg(27.0, form="textbook") == pytest.approx(
        sigma_phase_deg(27.0) / (2 * math.pi)
    )


def test_phase_sigma_grows_off_boresight() -> None:
    assert sigma_phase_deg(27.0, 60.0) == pytest.approx(2 * sigma_phase_deg(27.0))
    with pytest.raises(ValueError, match="theta"):
        sigma_phase_deg(27.0, 90.0)


def test_overrides_and_limits() -> None:
    assert link_budget(100.0, "wifi", pt_dbm=17.0).rx_power_dbm == pytest.approx(-85.802, abs=5e-4)
    with pytest.raises(ConfigError, match="EIRP"):
        link_budget(100.0, "wifi", pt_dbm=28.0)
    with pytest.raises(ConfigError, match="unknown link-budget parameter 'power'"):
        link_budget(100.0, "wifi", power=3)
    with pytest.raises(ConfigError, match="unknown radio"):
        link_budget(100.0, "zigbee")


def test_vectorised_distances() -> None:
    d = np.array([25.0, 100.0])
    b = link_budget(d, "wifi")
    assert np.allclose(b.path_loss_db, [69.72, 93.802], atol=5e-4)
