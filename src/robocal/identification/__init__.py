"""Geometric identification: the calibration model (chain + tracker frame + tools), identifiability and the
fitted parameters as a value (``ParameterSpec``), gross-error tests, noise estimates, the one ``FitResult``. The
least-squares core and the optimizers are :mod:`robocal.optimizers`; the calibration's steps are
:mod:`robocal.calibration`. Importing it reads and writes nothing."""
