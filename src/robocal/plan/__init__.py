"""Measurement planning: choose the calibration poses before the tracker is switched on (``robocal plan``).

:func:`plan_poses` draws candidates, refuses what the cell does not allow (counted by reason), selects a D-, A-
or I-optimal design by exchange on the identification Jacobian of the identifiable parameters, and predicts
the standard errors, the error map over a validation region and the poses needed for an accuracy.
:func:`write_plan` writes ``plan.csv``, ``plan.json`` and ``report.html``.
"""

from robocal.plan.config import PlanConfig
from robocal.plan.output import run_plan, write_plan
from robocal.plan.planner import PlanResult, build_problem, plan_poses, random_poses
from robocal.plan.prediction import predict
from robocal.plan.region import cell_from_scenario

__all__ = [
    "PlanConfig",
    "PlanResult",
    "build_problem",
    "cell_from_scenario",
    "plan_poses",
    "predict",
    "random_poses",
    "run_plan",
    "write_plan",
]
