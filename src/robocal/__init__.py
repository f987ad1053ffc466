"""robocal: industrial robot calibration from laser-tracker measurements."""

__version__ = "0.1.0"
