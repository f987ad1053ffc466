"""The one controller CSV (``compensation.csv``): one row per target, one layout, written by the thermal,
compliance and discovery workflows alike (:func:`write_controller_csv`; columns :data:`CSV_COLUMNS`)."""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from robocal.io import atomic_write
from robocal.kinematics.transforms import matrix_to_quat

#: Columns of ``compensation.csv`` and what they hold.
CSV_COLUMNS = {
    "target_id": "target id (pose id / target name)",
    "status": "ok | flagged | refused (the one safety policy, robocal.compensation.safety)",
    "applied": "1 = the corrected joints below were computed by the compensation; 0 = nominal joints kept",
    "q<j>_deg": "joint command to send, deg: corrected when applied = 1, else the requested (nominal) joints "
    "(q<j>_mm, mm, for a prismatic joint: a track, a column)",
    "x_mm, y_mm, z_mm": "Cartesian command for the nominal controller (robot base frame, tool point), mm",
    "qw, qx, qy, qz": "orientation of that command (unit quaternion, tool frame in the robot base frame)",
    "pred_err_mm": "predicted position error (mm) of the robot when sent this row",
    "pred_err_deg": "predicted orientation error (deg) likewise (when the compensation matched orientation)",
    "correction_max_deg": "largest |corrected - requested| joint angle the compensation computed, deg (also "
    "for rows that were not applied)",
    "extrapolation_C": "how far the temperature reading lies outside the thermal model's fitted range, worst "
    "sensor, degC (0 = inside or no thermal model)",
    "reason": "why the row is not ok (empty when ok)",
}


def write_controller_csv(
    path: str | Path,
    ids: Sequence[str] | np.ndarray,
    q: np.ndarray,
    command_T: np.ndarray,
    residual_mm: np.ndarray,
    residual_rad: np.ndarray | None,
    status: Sequence[str] | np.ndarray,
    applied: np.ndarray,
    correction_max_deg: np.ndarray,
    reason: Sequence[str] | np.ndarray,
    extrapolation_C: float = 0.0,
    prismatic: np.ndarray | None = None,
) -> Path:
    """Write ``compensation.csv``: joints ``q`` (m, n) rad to send, their nominal Cartesian command
    ``command_T`` (m, 4, 4), the predicted error when sent that row ``residual_mm`` (m, 3) and, when the
    orientation was matched, ``residual_rad`` (m, 3) (else None: no ``pred_err_deg`` column), the status,
    whether the correction is applied, the largest joint correction computed (deg) and the reasons.
    ``prismatic`` (n,) bool: joints whose value is a length (a track, a column), written in mm as ``q<j>_mm``."""
    qd = np.rad2deg(np.asarray(q, dtype=float))
    quat = matrix_to_quat(command_T[:, :3, :3])
    n = qd.shape[1]
    qcols = [f"q{j + 1}_deg" for j in range(n)]
    if prismatic is not None and np.any(prismatic):
        from robocal.data.columns import joint_columns

        qd = np.where(prismatic, np.asarray(q, dtype=float), qd)
        qcols = joint_columns(prismatic)
    head = ["target_id", "status", "applied", *qcols]
    head += ["x_mm", "y_mm", "z_mm", "qw", "qx", "qy", "qz", "pred_err_mm"]
    if residual_rad is not None:
        head.append("pred_err_deg")
    head += ["correction_max_deg", "extrapolation_C", "reason"]
    err = np.linalg.norm(np.atleast_2d(residual_mm), axis=1)
    erd = None if residual_rad is None else np.rad2deg(np.linalg.norm(np.atleast_2d(residual_rad), axis=1))
    rows = []
    for k, tid in enumerate(ids):
        vals = [str(tid), str(status[k]), str(int(applied[k]))]
        vals += [f"{v:.6f}" for v in qd[k]] + [f"{v:.6f}" for v in command_T[k, :3, 3]]
        vals += [f"{v:.9f}" for v in quat[k]] + [f"{err[k]:.6f}"]
        if erd is not None:
            vals.append(f"{erd[k]:.6f}")
        vals += [f"{correction_max_deg[k]:.6f}", f"{extrapolation_C:.3f}", str(reason[k])]
        rows.append(vals)

    def _write(p: Path) -> None:
        with p.open("w", newline="", encoding="utf-8") as f:
            w = csv.writer(f, lineterminator="\n")
            w.writerow(head)
            w.writerows(rows)

    return atomic_write(path, _write)
