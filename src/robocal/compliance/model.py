"""The identified joint-compliance model: joint deflections from motor currents, joint torques or gravity.

Mao et al. (2021), eq. 21-22: each reducer is a linear torsion spring, so the deflection of joint ``j`` is
``dq_j = c_j · s_j`` with ``s_j`` the signal that drives it:

- ``kind = "current"``: the motor current ``I_j`` (A), ``c_j = C_e phi_j / k_j`` in rad/A (the paper);
- ``kind = "torque"``: the joint torque reported by the drive (N·m), ``c_j = 1 / k_j`` in rad/(N·m);
- ``kind = "gravity"``: the gravity load torque computed from the link masses and the payload
  (:func:`robocal.kinematics.gravity.gravity_torques`), rad/(N·m), for campaigns without currents or torques.

The true joint angle is the commanded one plus ``dq``; the compensation (eq. 27) commands ``q* = q_n - dq``
to first order (the paper writes ``theta* = theta_n + I c`` with the opposite sign convention for ``c``).

:meth:`ComplianceModel.joint_offsets` is the one call an online service needs; the model round-trips through
:meth:`to_dict` / :meth:`from_dict` (JSON).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from robocal.errors import ConfigError
from robocal.robot import RobotDescription

KINDS = ("current", "torque", "gravity")
UNITS = {"current": "rad/A", "torque": "rad/(N·m)", "gravity": "rad/(N·m)"}


@dataclass
class ComplianceModel:
    """Per-joint compliance ``c`` with standard errors.

    Attributes
    ----------
    kind : str
        ``"current"``, ``"torque"`` or ``"gravity"`` (what drives the deflection).
    robot : str
        Robot name (``conf/robot/<name>.yaml``); needed to compute gravity torques for ``kind="gravity"``.
    joint_names : tuple of str, shape (n,)
    c : ndarray, shape (n,)
        Compliance per joint, rad/A or rad/(N·m); 0 where not identified.
    stderr : ndarray, shape (n,)
        Standard errors, NaN where not identified.
    identified : ndarray of bool, shape (n,)
    dynamics : dict
        For ``kind="gravity"``: ``link_mass_kg``, ``link_com_mm``, ``payload_com_mm``, ``gravity_mps2`` used in the
        fit (so the online torques are computed exactly as in the fit).
    info : dict
        Free-form provenance (fit statistics, method, campaign).
    """

    kind: str
    robot: str
    joint_names: tuple[str, ...]
    c: np.ndarray
    stderr: np.ndarray
    identified: np.ndarray
    dynamics: dict[str, Any] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)
    _robot_desc: RobotDescription | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ConfigError(f"The 'kind' of a ComplianceModel must be one of {list(KINDS)}. Got {self.kind!r}.")
        n = len(self.joint_names)
        self.c = np.asarray(self.c, dtype=float).reshape(-1)
        self.stderr = np.asarray(self.stderr, dtype=float).reshape(-1)
        self.identified = np.asarray(self.identified, dtype=bool).reshape(-1)
        for name, v in (("c", self.c), ("stderr", self.stderr), ("identified", self.identified)):
            if v.shape != (n,):
                raise ConfigError(f"ComplianceModel: '{name}' must have {n} entries (one per joint). Got {v.shape}.")

    # ------------------------------------------------------------------------------------------ basics
    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def unit(self) -> str:
        return UNITS[self.kind]

    def with_robot(self, robot: RobotDescription) -> ComplianceModel:
        """Attach the robot description (used for gravity torques instead of loading ``robot`` by name)."""
        if robot.n_joints != self.n_joints:
            raise ConfigError(f"robot {robot.name!r} has {robot.n_joints} joints, the model {self.n_joints}")
        self._robot_desc = robot
        return self

    def _robot(self) -> RobotDescription:
        if self._robot_desc is None:
            from robocal.robot import load_robot

            self._robot_desc = load_robot(self.robot)
        return self._robot_desc

    # -------------------------------------------------------------------------------------- prediction
    def signal(
        self,
        q: np.ndarray,
        payload_kg: np.ndarray | float,
        current_A: np.ndarray | None = None,
        tau_Nm: np.ndarray | None = None,
    ) -> np.ndarray:
        """The deflection-driving signal ``(m, n)``: currents (A) or torques (N·m) by ``kind``."""
        q = np.asarray(q, dtype=float)
        n = self.n_joints
        if q.ndim != 2 or q.shape[1] != n:
            raise ValueError(f"The 'q' parameter of joint_offsets must have shape (m, {n}). Got {q.shape} instead.")
        m = q.shape[0]
        if self.kind == "current":
            if current_A is None:
                raise ValueError("The 'current_A' parameter of joint_offsets is required for a current-based model.")
            s = np.asarray(current_A, dtype=float)
            name = "current_A"
        elif self.kind == "torque":
            if tau_Nm is None:
                raise ValueError("The 'tau_Nm' parameter of joint_offsets is required for a torque-based model.")
            s = np.asarray(tau_Nm, dtype=float)
            name = "tau_Nm"
        else:
            from robocal.kinematics.gravity import gravity_torques

            pl = np.asarray(payload_kg, dtype=float)
            if pl.ndim not in (0, 1) or (pl.ndim == 1 and pl.shape != (m,)):
                raise ValueError(f"The 'payload_kg' parameter of joint_offsets must be a number or shape ({m},).")
            if pl.size and np.any(pl < 0):
                raise ValueError("The 'payload_kg' parameter of joint_offsets must be >= 0.")
            d = self.dynamics
            rob = self._robot()
            s = gravity_torques(
                rob,
                q,
                pl,
                link_mass_kg=np.asarray(d["link_mass_kg"]) if "link_mass_kg" in d else None,
                link_com_mm=np.asarray(d["link_com_mm"]) if "link_com_mm" in d else None,
                payload_com_mm=np.asarray(d["payload_com_mm"]) if "payload_com_mm" in d else None,
                gravity=np.asarray(d["gravity_mps2"]) if "gravity_mps2" in d else None,
            )
            name = "computed torque"
        if s.shape != (m, n) or not np.all(np.isfinite(s)):
            raise ValueError(f"The '{name}' of joint_offsets must be finite with shape ({m}, {n}). Got {s.shape}.")
        return s

    def joint_offsets(
        self,
        q: np.ndarray,
        payload_kg: np.ndarray | float,
        current_A: np.ndarray | None = None,
        tau_Nm: np.ndarray | None = None,
    ) -> np.ndarray:
        """Predicted joint deflections ``dq (m, n)`` rad: true joint = commanded + dq.

        Parameters
        ----------
        q : ndarray, shape (m, n)
            Commanded joint angles, rad.
        payload_kg : float or ndarray, shape (m,)
            Payload on the flange (used by ``kind="gravity"``).
        current_A : ndarray, shape (m, n), optional
            Motor currents (required by ``kind="current"``).
        tau_Nm : ndarray, shape (m, n), optional
            Joint torques reported by the drives (required by ``kind="torque"``).
        """
        return self.signal(q, payload_kg, current_A, tau_Nm) * self.c

    # ------------------------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict[str, Any]:
        joints = []
        for j, name in enumerate(self.joint_names):
            joints.append(
                {
                    "joint": j + 1,
                    "name": name,
                    "c": float(self.c[j]),
                    "stderr": None if not np.isfinite(self.stderr[j]) else float(self.stderr[j]),
                    "identified": bool(self.identified[j]),
                    "stiffness": (1.0 / float(self.c[j])) if self.identified[j] and self.c[j] != 0 else None,
                }
            )
        return {
            "format": "robocal.compliance/1",
            "kind": self.kind,
            "unit": self.unit,
            "stiffness_unit": "A/rad" if self.kind == "current" else "N·m/rad",
            "robot": self.robot,
            "joints": joints,
            "dynamics": {k: np.asarray(v).tolist() for k, v in self.dynamics.items()},
            "info": self.info,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any], robot: RobotDescription | None = None) -> ComplianceModel:
        """Rebuild from :meth:`to_dict` output (also accepts a ``compliance.json`` holding it under ``model``)."""
        if "model" in data and isinstance(data["model"], dict):
            data = data["model"]
        try:
            joints = sorted(data["joints"], key=lambda r: int(r["joint"]))
            model = cls(
                kind=str(data["kind"]),
                robot=str(data.get("robot", "")),
                joint_names=tuple(str(r["name"]) for r in joints),
                c=np.array([float(r["c"]) for r in joints]),
                stderr=np.array([np.nan if r.get("stderr") is None else float(r["stderr"]) for r in joints]),
                identified=np.array([bool(r.get("identified", True)) for r in joints]),
                dynamics=dict(data.get("dynamics") or {}),
                info=dict(data.get("info") or {}),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"not a compliance model (robocal.compliance/1): {exc!r}") from None
        if robot is not None:
            model.with_robot(robot)
        return model

    @classmethod
    def from_json(cls, path: str | Path, robot: RobotDescription | None = None) -> ComplianceModel:
        p = Path(path)
        if not p.is_file():
            raise ConfigError(f"compliance model file {p} does not exist")
        try:
            data = json.loads(p.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise ConfigError(f"{p}: not valid JSON: {exc}") from None
        return cls.from_dict(data, robot)


__all__ = ["KINDS", "UNITS", "ComplianceModel"]
