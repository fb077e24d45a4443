"""RF physics: path loss, link budget, angle-error formulas, antenna patterns, RSSI models."""

from rfsas_hw.rf.antenna import GaussianBeamPair
from rfsas_hw.rf.aoa import db_to_linear, sigma_monopulse_deg, sigma_phase_deg
from rfsas_hw.rf.link_budget import RADIOS, LinkBudget, RadioParams, link_budget, radio_params
from rfsas_hw.rf.noise import quantisation_variance_db2, quantise_db, rssi_sigma_db
from rfsas_hw.rf.propagation import (
    TABLE_OFFSET_DB,
    free_space_path_loss_db,
    path_loss_db,
    two_ray_breakpoint_path_loss_db,
    two_ray_coherent_path_loss_db,
    two_ray_table_path_loss_db,
    wavelength_m,
)
from rfsas_hw.rf.synth import ReceiverModel, TurntableSamples, rssi_pairs, turntable_sweep

__all__ = [
    "RADIOS",
    "TABLE_OFFSET_DB",
    "GaussianBeamPair",
    "LinkBudget",
    "RadioParams",
    "ReceiverModel",
    "TurntableSamples",
    "db_to_linear",
    "free_space_path_loss_db",
    "link_budget",
    "path_loss_db",
    "quantisation_variance_db2",
    "quantise_db",
    "radio_params",
    "rssi_pairs",
    "rssi_sigma_db",
    "sigma_monopulse_deg",
    "sigma_phase_deg",
    "turntable_sweep",
    "two_ray_breakpoint_path_loss_db",
    "two_ray_coherent_path_loss_db",
    "two_ray_table_path_loss_db",
    "wavelength_m",
]
