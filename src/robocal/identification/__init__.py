"""Geometric identification: the calibration model (chain + tracker frame + tools), identifiability, the one
least-squares core (Gauss-Newton / Levenberg-Marquardt), gross-error screening, noise estimates, the one
``FitResult`` and the steps of a calibration (:mod:`robocal.calibration`; the entry point with its
solve step is :func:`robocal.calibration.fit.calibrate`). Importing it reads and writes nothing."""
