"""One calibration package (issue 32): the geometric fit's steps live in ``robocal/calibration/``, a module for
each role and none over 600 lines; ``robocal.calibrate`` is its ``fit.calibrate``; the old module paths define
nothing (they only hand names on to the branches that still import them)."""

from __future__ import annotations

from pathlib import Path

import robocal

SRC = Path(__file__).resolve().parents[2] / "src" / "robocal"
# the axis errors and a positioner fitted on top of a calibration are roles of the package too
ROLES = {"config", "start", "problem", "solve", "screening", "result", "record", "load", "validation", "fit", "axes",
         "positioner"}  # fmt: skip
OLD_PATHS = ("identification/calibrate.py", "optimizers/geometric.py", "identification/axes.py",
             "identification/positioner.py")  # fmt: skip


def test_a_module_for_each_role_none_over_600_lines() -> None:
    modules = {p.stem: p for p in (SRC / "calibration").glob("*.py") if p.stem != "__init__"}
    assert set(modules) == ROLES
    long = {name: n for name, p in modules.items() if (n := len(p.read_text(encoding="utf-8").splitlines())) > 600}
    assert not long, long


def test_the_public_names_come_from_the_package() -> None:
    from robocal.calibration import config, fit, load, result, validation

    assert robocal.calibrate is fit.calibrate
    assert robocal.CalibrationConfig is config.CalibrationConfig
    assert robocal.CalibrationResult is result.CalibrationResult
    assert robocal.load_calibration is load.load_calibration
    assert robocal.validate is validation.validate


def test_the_old_paths_are_gone() -> None:
    for rel in (*OLD_PATHS, "optimizers/calibration.py"):
        assert not (SRC / rel).exists(), f"{rel}: the calibration lives in robocal.calibration"
