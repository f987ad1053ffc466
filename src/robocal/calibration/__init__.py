"""The geometric calibration, one package with a module for each role (import from the module; the public names
are ``robocal.calibrate``, ``robocal.CalibrationConfig`` ...):

* :mod:`~robocal.calibration.config`: the settings (``CalibrationConfig``) and each point's noise;
* :mod:`~robocal.calibration.start`: registration, the nominal model's best rigid fit, the identifiable parameters;
* :mod:`~robocal.calibration.problem`: the calibration as an optimizer :class:`~robocal.optimizers.protocol.Problem`;
* :mod:`~robocal.calibration.solve`: the solve step, any registered optimizer through the one protocol;
* :mod:`~robocal.calibration.screening`: gross errors left out, systematic misfits named;
* :mod:`~robocal.calibration.result`: :class:`~robocal.calibration.result.CalibrationResult` and its statistics;
* :mod:`~robocal.calibration.record`, :mod:`~robocal.calibration.load`: ``calibration.json`` written and read;
* :mod:`~robocal.calibration.validation`: errors on the validation rows;
* :mod:`~robocal.calibration.fit`: ``calibrate`` (``robocal.calibrate``), dispatching on the optimizer;
* :mod:`~robocal.calibration.axes`, :mod:`~robocal.calibration.positioner`: on top of a calibration, an external
  axis's own errors along its travel and a positioner carrying the part.
"""
