"""The old path of :func:`robocal.calibrate`, now :mod:`robocal.calibration.fit`: handed on for discovery's import
(to be removed once it names the package)."""

from __future__ import annotations

from robocal.calibration.fit import calibrate

__all__ = ["calibrate"]
