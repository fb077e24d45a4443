"""Monopulse direction finding: the ratio, calibration tables and the bearing estimator."""

from rfsas_hw.df.calfile import (
    calibration_from_mapping,
    calibration_to_mapping,
    load_calibration,
    save_calibration,
)
from rfsas_hw.df.calibration import Calibration, CalibrationTable, fit_calibration, fit_table
from rfsas_hw.df.estimate import DfFlag, DfResult, estimate
from rfsas_hw.df.monopulse import MODES, Mode, balance_k_d, ratio, ratio_gradient
from rfsas_hw.df.samples import read_samples_csv, write_samples_csv

__all__ = [
    "MODES",
    "Calibration",
    "CalibrationTable",
    "DfFlag",
    "DfResult",
    "Mode",
    "balance_k_d",
    "calibration_from_mapping",
    "calibration_to_mapping",
    "estimate",
    "fit_calibration",
    "fit_table",
    "load_calibration",
    "ratio",
    "ratio_gradient",
    "read_samples_csv",
    "save_calibration",
    "write_samples_csv",
]
