"""A drift in time is judged on spans of time it was not fitted on, and not carried past the rows that showed it
(newcomer pass 9: 18 configurations of a heavy robot measured one after the other; a linear drift stood for a
misfit the measurement order followed, passed the pose-grouped cross-validation, and was extrapolated 90 minutes
to the validation rows: 0.84 mm held out where the geometry alone had 0.65 and the model without it 0.18)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from robocal.discovery.ftest import cross_validation_gain, time_blocks
from robocal.discovery.validate import drift_signal


def _gains(r: np.ndarray, t: np.ndarray, n: int) -> tuple[float, float]:
    """The cross-validated gain of a linear trend in ``t`` over a constant: poses held out, spans held out."""
    fit = SimpleNamespace(r_w=r, J_w=np.ones((len(t), 1)))
    U = (t - t.mean())[:, None]
    U = U / np.linalg.norm(U)
    poses = np.repeat(np.arange(n), 3).astype(str)
    return cross_validation_gain(fit, U, poses, 5, 0), cross_validation_gain(fit, U, time_blocks(t, 5, 1), 5, 0)


def test_a_trend_that_does_not_hold_beyond_its_rows_fails_the_time_blocks():
    rng = np.random.default_rng(0)
    n = 60  # configurations measured in turn, three rows each
    t = np.repeat(np.arange(n), 3) + rng.uniform(0, 0.3, 3 * n)
    # a misfit that bends back over the campaign: neighbours in time predict each other, the trend does not hold
    r = np.sin(2 * np.pi * 0.7 * t / n) + rng.normal(0, 0.1, len(t))
    by_pose, by_span = _gains(r, t, n)
    assert by_pose > 0.3 and by_span < 0  # (0.45 and -0.21 on this seed: the defect passed by the first)
    # a true drift passes both
    by_pose, by_span = _gains(0.02 * (t - t.mean()) + rng.normal(0, 0.1, len(t)), t, n)
    assert by_pose > 0.5 and by_span > 0.5


def test_time_blocks_are_consecutive_spans_of_equal_counts():
    t = np.array([5.0, 1.0, 3.0, 2.0, 4.0, 0.0])
    b = time_blocks(t, 3, 2)
    assert list(b) == ["t2", "t2", "t0", "t0", "t1", "t1", "t1", "t1", "t2", "t2", "t0", "t0"]


def test_a_drift_in_time_is_held_at_the_ends_of_the_fitted_rows():
    t = np.linspace(-1.0, 2.0, 7)[:, None]  # hours; rows 0-3 fitted, 4-6 measured later
    drift = SimpleNamespace(effect="drift", S=t)
    other = SimpleNamespace(effect="thermal", S=t)
    fitted = np.arange(4)
    assert np.allclose(drift_signal(drift, np.arange(7), fitted)[:, 0], [-1.0, -0.5, 0.0, 0.5, 0.5, 0.5, 0.5])
    assert np.allclose(drift_signal(other, np.arange(7), fitted), t)  # a temperature's drift follows it
