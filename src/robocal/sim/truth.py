"""Compare a calibration with the twin's truth in the identified parameterisation.

Eliminated parameters are held at nominal, so their true errors are carried by the parameters that
absorb them (d6 by the tool z, theta1 by the base rz, ...). The fair "true value" of each identified
parameter is therefore the one that reproduces the true robot exactly with the same identified set:
it is found by fitting the calibrated model to noise-free truth positions at the same poses.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from robocal.calibration.result import CalibrationResult
from robocal.identification.model import FitData
from robocal.kinematics.chain import build_chain, propagate
from robocal.metrics import ErrorStats
from robocal.optimizers.least_squares import least_squares
from robocal.robot import RobotDescription


def truth_positions(truth: dict[str, Any], robot: RobotDescription, q: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Noise-free target positions ``(m, 3)`` (tracker frame) of the true geometric robot (no effects).

    ``targets`` holds the target name per row.
    """
    chain = build_chain(robot)
    eta = np.array([truth["kinematic_errors"][n] for n in chain.param_names])
    T = np.array(truth["tracker_T_base"])
    st = propagate(chain, q, eta, T)
    t = np.array([truth["tools_mm"][str(name)] for name in targets])
    return st.o + st.x * t[:, 0:1] + st.y * t[:, 1:2] + st.z * t[:, 2:3]


def equivalent_truth(
    result: CalibrationResult, truth: dict[str, Any], q: np.ndarray, target_index: np.ndarray
) -> tuple[np.ndarray, float]:
    """True parameter values in the result's identified parameterisation.

    Returns ``(x_equiv (n,), rms_mm)`` where ``rms_mm`` is the RMS misfit of that representation to the
    truth (about 0 when the identified set spans the true errors).
    """
    model = result.model
    names = np.array(model.target_names, dtype=object)[target_index]
    p_true = truth_positions(truth, model.robot, q, names)
    data = FitData(q=q, p_mm=p_true, target_index=target_index)
    free = np.flatnonzero(result.identified)

    def fun(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return model.residuals_and_jacobian(x, data)

    lm = least_squares(fun, result.x.copy(), free, 1.0, max_iter=50, ftol=1e-15, xtol=1e-13)
    rms = ErrorStats.of(lm.residual.reshape(-1, 3)).rms_mm
    return np.array(lm.x), rms


def z_scores(
    result: CalibrationResult, truth: dict[str, Any], q: np.ndarray, target_index: np.ndarray
) -> dict[str, float]:
    """``(estimate - equivalent truth) / standard error`` per identified parameter."""
    x_eq, _ = equivalent_truth(result, truth, q, target_index)
    idx = np.flatnonzero(result.identified)
    return {result.names[i]: float((result.x[i] - x_eq[i]) / result.stderr[i]) for i in idx}
