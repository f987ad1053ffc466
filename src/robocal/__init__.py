"""robocal: industrial robot calibration from laser-tracker measurements.

The public API (imported lazily: ``import robocal`` itself reads and loads nothing heavy)::

    import robocal

    robot = robocal.load_robot("kr16_2")                       # or a YAML path
    campaign = robocal.read_campaign("path/to/campaign", robot)  # the data contract, checked
    result = robocal.calibrate(campaign, robot)                # geometric calibration (gross errors handled)
    other = robocal.calibrate(campaign, robot, optimizer="igoa")  # any registered optimizer (gn lm ipopt goa woa)
    print(result.fit["rms_position_mm"], result.fit["outliers"])
    print(result.solver.redchi, result.solver.bic)              # the fit itself: a FitResult (immutable)
    print(robocal.validate(result, campaign))                  # errors on the validation rows
    found = robocal.discover(campaign, robot)                  # what the model misses, named
    c = robocal.compensate(result, q_rad)                      # corrected joints c.q, c.command_T, c.status
    planned = robocal.plan("kr16_2", {"n_poses": 40})          # the poses to measure, before the tracker is on

``simulate`` / ``load_scenario`` write twin campaigns with a known truth; ``load_calibration`` reads a
``calibration.json`` back (including the effects discovery wrote into it).
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

#: public name -> "module:attribute"
_API = {
    "read_campaign": "robocal.data.contract:read_campaign",
    "Campaign": "robocal.data.campaign:Campaign",
    "load_robot": "robocal.robot:load_robot",
    "RobotDescription": "robocal.robot:RobotDescription",
    "calibrate": "robocal.calibration.fit:calibrate",
    "validate": "robocal.calibration.validation:validate",
    "CalibrationConfig": "robocal.calibration.config:CalibrationConfig",
    "CalibrationResult": "robocal.calibration.result:CalibrationResult",
    "load_calibration": "robocal.calibration.load:load_calibration",
    "FitResult": "robocal.identification.result:FitResult",
    "discover": "robocal.discovery.search:discover",
    "DiscoveryConfig": "robocal.discovery.config:DiscoveryConfig",
    "compensate": "robocal.compensation.correct:correct",
    "Corrected": "robocal.compensation.correct:Corrected",
    "plan": "robocal.plan.planner:plan_poses",
    "simulate": "robocal.sim.twin:simulate",
    "load_scenario": "robocal.sim.scenario:load_scenario",
}

__all__ = ["__version__", *_API]


def __getattr__(name: str) -> Any:
    spec = _API.get(name)
    if spec is None:
        raise AttributeError(f"module 'robocal' has no attribute {name!r}")
    mod, attr = spec.split(":")
    value = getattr(importlib.import_module(mod), attr)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
