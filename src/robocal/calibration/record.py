"""The ``calibration.json`` record of a calibration (:func:`calibration_record`) and the robot it was made for
(:func:`nominal_record`, :func:`check_robot`)."""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.calibration.config import WRITTEN_WHEN_SET, CalibrationConfig
from robocal.errors import ConfigError
from robocal.identification.identifiability import Identifiability
from robocal.identification.model import CalibrationModel
from robocal.kinematics.transforms import rpy_from_matrix
from robocal.robot import MDH, RobotDescription

if TYPE_CHECKING:
    pass


def correlation_of(covariance: np.ndarray) -> np.ndarray:
    """The correlation matrix of a covariance (a zero variance reads as 1: its row and column stay 0)."""
    d = np.sqrt(np.diag(covariance))
    d[d == 0] = 1.0
    return covariance / np.outer(d, d)


def parameter_table(
    model: CalibrationModel, x: np.ndarray, stderr: np.ndarray, identified: np.ndarray, fixed: tuple[str, ...]
) -> list[dict[str, Any]]:
    """One row per parameter of ``model``: value and standard error in display units (mm, deg) and status
    (identified, fixed by the user, or eliminated)."""
    rows = []
    for k, name in enumerate(model.names):
        unit = model.units[k]
        f = np.rad2deg(1.0) if unit == "rad" else 1.0
        rows.append(
            {
                "name": name,
                "kind": model.kinds[k],
                "unit": "deg" if unit == "rad" else unit,
                "value": float(x[k] * f),
                "stderr": float(stderr[k] * f) if identified[k] else None,
                "status": "identified" if identified[k] else ("fixed" if name in fixed else "eliminated"),
            }
        )
    return rows


def calibration_record(
    model: CalibrationModel,
    x: np.ndarray,
    identified: np.ndarray,
    stderr: np.ndarray,
    covariance: np.ndarray,
    identifiability: Identifiability,
    fixed: tuple[str, ...],
    fit: Mapping[str, Any],
    config: CalibrationConfig,
) -> dict[str, Any]:
    """The ``calibration.json`` record of a calibration given by its parts (what :func:`load_calibration`
    reads back): :meth:`CalibrationResult.to_dict`, and any model that writes the geometric format (the
    discovered model's geometry) without being a fitted :class:`CalibrationResult`.

    x : (n,) every parameter of ``model``; identified : (n,) bool; stderr : (n,) NaN where not identified;
    covariance : (k, k) over the identified ones; fixed : parameters fixed by the user; fit : the fit record
    (``fit`` of the file); config : the settings recorded under ``config``."""
    T = model.base_transform(x)
    idx = np.flatnonzero(identified)
    names = model.names
    elim = identifiability.eliminated
    return {
        "robot": model.robot.name,
        "convention": model.robot.convention,
        "nominal": nominal_record(model.robot),
        "parameters": parameter_table(model, x, stderr, identified, fixed),
        "kinematic_errors": {n: float(x[k]) for k, n in enumerate(model.chain.param_names)},
        "eliminated": [e.to_dict() for e in elim],
        "fixed": list(fixed),
        "tracker_T_base": T.tolist(),
        "tracker_T_base_xyz_mm": T[:3, 3].tolist(),
        "tracker_T_base_rpy_deg": np.rad2deg(rpy_from_matrix(T[:3, :3])).tolist(),
        "tools_mm": {name: t.tolist() for name, t in zip(model.target_names, model.tools(x), strict=True)},
        "tool_rotations": {k: R.tolist() for k, R in zip(model.target_names, model.tool_rotations(x), strict=True)},
        "stations": list(model.station_names),
        "stations_T_base": {s: model.base_transform(x, k).tolist() for k, s in enumerate(model.station_names)},
        "station_T_ref": model.station_T_ref.tolist(),
        "T_ref": model.T_ref.tolist(),
        "tool_R_ref": model.tool_R_ref.tolist(),
        "orientation": model.orientation,
        "x": x.tolist(),
        "names": list(names),
        "correlation": {
            "names": [names[i] for i in idx],
            "matrix": correlation_of(covariance).tolist(),
        },
        "identifiability": {
            "rank": identifiability.rank,
            "n_candidates": int(len(identifiability.kept) + len(elim)),
            "condition_number": identifiability.condition_number,
        },
        "fit": fit,
        "config": {
            k: getattr(config, k)
            for k, f in config.__dataclass_fields__.items()
            if k not in WRITTEN_WHEN_SET or getattr(config, k) != f.default
        },
    }


#: tolerance of the nominal-table comparison (mm and deg): calibration.json keeps 9 significant digits
NOMINAL_TOL = 1e-6


def nominal_record(robot: RobotDescription) -> dict[str, Any]:
    """The robot's nominal kinematics as ``calibration.json`` records them (``nominal``), so that a calibration
    is never applied to another robot (:func:`check_robot`): the joint names and the MD-H table (mm, deg) or
    the POE twists and flange pose at zero."""
    out: dict[str, Any] = {
        "convention": robot.convention,
        "n_joints": robot.n_joints,
        "joints": list(robot.joint_names),
    }
    if robot.is_mdh:
        out["mdh"] = {
            "a_mm": robot.a_mm.tolist(),
            "alpha_deg": np.rad2deg(robot.alpha).tolist(),
            "d_mm": robot.d_mm.tolist(),
            "theta_offset_deg": np.rad2deg(robot.theta_offset).tolist(),
            "beta_deg": np.rad2deg(robot.beta).tolist(),
        }
    else:
        assert robot.poe_w is not None and robot.poe_p_mm is not None and robot.poe_flange0 is not None
        out["poe"] = {"w": robot.poe_w.tolist(), "p_mm": robot.poe_p_mm.tolist(), "flange0": robot.poe_flange0.tolist()}
    return out


def check_robot(data: dict[str, Any], robot: RobotDescription, where: str = "the calibration") -> None:
    """Refuse a calibration made for another robot: its recorded robot name, joint count and (when recorded)
    nominal table must be ``robot``'s. The error names both robots."""
    theirs = data.get("robot")
    rec = data.get("nominal")
    n_theirs = rec.get("n_joints") if isinstance(rec, dict) else None
    if n_theirs is None and data.get("convention") == MDH and isinstance(data.get("names"), list):
        # older files (no nominal record): one MD-H theta<i> per joint
        n_theirs = sum(1 for n in data["names"] if re.fullmatch(r"theta\d+", str(n)))
    problems = []
    if theirs is not None and str(theirs) != robot.name:
        problems.append(f"it names robot {theirs!r}")
    if n_theirs is not None and int(n_theirs) != robot.n_joints:
        problems.append(f"it has {int(n_theirs)} joints, {robot.name!r} has {robot.n_joints}")
    if isinstance(rec, dict):
        mine = nominal_record(robot)
        if rec.get("convention") != mine["convention"]:
            problems.append(f"its convention is {rec.get('convention')!r}, {robot.name!r} uses {mine['convention']!r}")
        elif rec.get("n_joints") == mine["n_joints"]:
            section = "mdh" if robot.is_mdh else "poe"
            for key, ours in mine[section].items():
                a = np.asarray((rec.get(section) or {}).get(key), dtype=float)
                b = np.asarray(ours, dtype=float)
                if a.shape != b.shape or not np.allclose(a, b, rtol=NOMINAL_TOL, atol=NOMINAL_TOL):
                    if a.shape == b.shape and a.ndim == 1:
                        j = int(np.argmax(np.abs(a - b)))
                        problems.append(f"its nominal {key} of joint {j + 1} is {a[j]:g}, {robot.name!r} has {b[j]:g}")
                    else:
                        problems.append(f"its nominal {section} {key} differs from {robot.name!r}'s")
                    break
    if problems == [f"it names robot {theirs!r}"] and isinstance(rec, dict):
        problems.append("(the nominal tables agree: if it is the same robot, name the description it was made with)")
    if problems:
        raise ConfigError(
            f"{where} was made for robot {theirs!r}, not for {robot.name!r} ({robot.source or 'given'}): "
            f"{'; '.join(problems)}. Use the robot the calibration was made with."
        )
