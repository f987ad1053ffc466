"""A short closed loop on the twin's warm-up through the real server, thermal model fitted from the twin."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("robocal.sim.thermal") is None or importlib.util.find_spec("robocal.thermal") is None,
    reason="needs the thermal twin effect and the thermal model",
)


def test_short_warm_up(tmp_path):
    from robocal.serve.closed_loop import run_closed_loop, write_report

    res = run_closed_loop("thermal", tmp_path, seed=0, n_targets=8, interval_min=60.0, duration_min=120.0)
    E = res.errors_mm
    assert res.refused.sum() == 0
    # oracle = tracker noise only: mean |n| of a 3-D N(0, 15 um) is 24 um; 8 targets x 3 epochs -> within 40 %
    assert 0.6 * 0.024 < E["oracle"].mean() < 1.4 * 0.024
    # the service removes most of the ~1-2 mm error of the uncompensated twin (geometric + thermal)
    assert E["compensated"].mean() < 0.1 * E["uncompensated"].mean()
    assert np.isfinite(res.summary["max_ratio"])
    html = write_report(res, tmp_path, tracking=False)
    assert html.exists() and (tmp_path / "closed_loop_error.png").exists()
