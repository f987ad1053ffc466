"""The model as served must stand on its own (robocal.discovery.served): a robot-side effect that a measurement-side
one cancels is the one the held-out check drops."""

from __future__ import annotations

from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np

from robocal.discovery.served import served_conflict


@dataclass
class _Fit:
    """The few members of a fit the check reads: two effects' columns (whitened, weights 1), their estimates."""

    J: np.ndarray
    theta: np.ndarray
    r_w: np.ndarray
    model: object
    d: int = 3
    weights: np.ndarray = field(default_factory=lambda: np.ones(0))

    def __post_init__(self) -> None:
        self.M = len(self.r_w)
        self.free = np.arange(self.J.shape[1])
        self.weights = np.ones(self.M)

    def jacobian_columns(self, pos: np.ndarray) -> np.ndarray:
        return self.J[:, pos]

    @property
    def rms_mm(self) -> float:
        return float(np.sqrt(np.mean(np.sum(self.r_w.reshape(-1, 3) ** 2, axis=1))))


def _fit(scale: float) -> _Fit:
    """A thermal drift of the robot (param shape) and a tracker scale (tracker shape) fitted to the same cause:
    each ``scale`` mm, their sum the noise."""
    rng = np.random.default_rng(0)
    g = rng.standard_normal(300)
    J = np.column_stack([g, -g])  # opposite displacements per unit
    eff = [SimpleNamespace(cand=SimpleNamespace(key=k, shape=s, effect=e, extra={}))
           for k, s, e in (("thermal", "param", "thermal"), ("scale:drift", "tracker", "scale"))]  # fmt: skip
    model = SimpleNamespace(accepted=eff, slices=[slice(0, 1), slice(1, 2)])
    return _Fit(J, np.array([scale, scale]), 0.02 * rng.standard_normal(300), model)


def test_a_robot_effect_that_a_tracker_scale_cancels_is_the_one_dropped():
    """The UR10's grid series (12 000 rows): a thermal drift and tracker scales of the air temperature named
    together, the fit at 0.08 mm and the robot as served 183 mm off."""
    key, figures = served_conflict(_fit(50.0), geometric_rms_mm=0.44)
    assert key == "thermal" and figures["served_rms_mm"] > 10 * figures["geometric_rms_mm"]


def test_a_tracker_scale_that_leaves_the_served_model_better_than_the_geometry_is_kept():
    key, figures = served_conflict(_fit(0.05), geometric_rms_mm=0.44)  # 0.05 mm: a real scale's size
    assert key is None and figures["served_rms_mm"] < 0.44
    assert served_conflict(_fit(50.0), geometric_rms_mm=None) == (None, {})
