"""A calibration read back from its ``calibration.json`` record (:func:`load_calibration`)."""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.calibration.config import CalibrationConfig
from robocal.calibration.record import check_robot
from robocal.calibration.result import CalibrationResult
from robocal.errors import ConfigError
from robocal.identification.identifiability import Eliminated, Identifiability
from robocal.identification.model import CalibrationModel
from robocal.robot import RobotDescription

if TYPE_CHECKING:
    pass


def load_calibration(data: dict[str, Any], robot: RobotDescription) -> CalibrationResult:
    """Rebuild a :class:`CalibrationResult` (enough to predict and compensate) from :meth:`to_dict` output.

    A calibration written by discovery also carries joint-level ``effects`` (:attr:`CalibrationResult.effects`)
    and, when it freed a Hayati beta, the robot's ``beta_free``. A calibration of another robot (name, joint count,
    nominal table: :func:`check_robot`) is refused."""
    check_robot(data, robot)
    if "beta_free" in data:
        bf = np.array(data["beta_free"], dtype=bool)
        if bf.shape != np.shape(robot.beta_free):
            raise ConfigError(f"calibration 'beta_free' has {bf.shape[0]} joints; robot {robot.name!r} has another")
        robot = replace(robot, beta_free=bf)
    stations = tuple(data.get("stations") or ())
    model = CalibrationModel(
        robot,
        tuple(data["tools_mm"].keys()),
        orientation=bool(data.get("orientation", False)),
        T_ref=np.array(data["T_ref"]),
        tool_R_ref=np.array(data["tool_R_ref"]),
        stations=stations,
        station_T_ref=np.array(data["station_T_ref"]) if "station_T_ref" in data else None,
    )
    if list(model.names) != list(data["names"]):
        raise ConfigError(
            f"calibration file does not match robot {robot.name!r}: parameter names differ "
            f"({len(data['names'])} in file, {len(model.names)} for the robot)"
        )
    x = np.array(data["x"], dtype=float)
    identified = np.array([p["status"] == "identified" for p in data["parameters"]])
    se = np.array([np.nan if p["stderr"] is None else p["stderr"] for p in data["parameters"]], dtype=float)
    se = np.where(np.array(model.units) == "rad", np.deg2rad(se), se)
    k = int(identified.sum())
    corr = np.array(data["correlation"]["matrix"], dtype=float).reshape(k, k)
    cov = corr * np.outer(se[identified], se[identified])
    elim = tuple(
        Eliminated(
            e["name"],
            tuple((a["name"], a["coefficient"]) for a in e["absorbed_by"]),
            e["leftover"],
            e["reason"],
        )
        for e in data["eliminated"]
    )
    ident = Identifiability(
        kept=np.flatnonzero(identified),
        eliminated=elim,
        rank=int(data["identifiability"]["rank"]),
        singular_values=np.array([]),
        names=model.names,
    )
    cfg_d = {k: v for k, v in data["config"].items() if k in CalibrationConfig.__dataclass_fields__}
    cfg_d["fixed"] = tuple(cfg_d.get("fixed", ()))
    if isinstance(cfg_d.get("outliers"), list):
        cfg_d["outliers"] = tuple(cfg_d["outliers"])
    cfg = CalibrationConfig(**cfg_d)
    return CalibrationResult(
        model,
        x,
        identified,
        se,
        cov,
        ident,
        tuple(data.get("fixed", ())),
        dict(data["fit"]),
        np.zeros((0, 3)),
        None,
        cfg,
        effects=tuple(data.get("effects") or ()),
    )
