"""The old path of the geometric calibration's steps, now :mod:`robocal.calibration`: the names that discovery and
the service still import from here, handed on (to be removed once their imports name the package)."""

from __future__ import annotations

from robocal.calibration.config import CalibrationConfig, data_rows, outlier_rule
from robocal.calibration.load import load_calibration
from robocal.calibration.record import calibration_record, check_robot
from robocal.calibration.result import CalibrationResult
from robocal.calibration.screening import describe_outliers
from robocal.calibration.start import fit_data, present_stations, present_targets
from robocal.calibration.validation import Validation, validate, validate_rows

__all__ = [
    "CalibrationConfig",
    "CalibrationResult",
    "Validation",
    "calibration_record",
    "check_robot",
    "data_rows",
    "describe_outliers",
    "fit_data",
    "load_calibration",
    "outlier_rule",
    "present_stations",
    "present_targets",
    "validate",
    "validate_rows",
]
