"""Geometric identification: the calibration model (chain + tracker frame + tools), identifiability, the one
least-squares core (Gauss-Newton / Levenberg-Marquardt), gross-error screening, noise estimates, the one
``FitResult`` and :func:`robocal.identification.calibrate.calibrate`. Importing it reads and writes nothing."""
