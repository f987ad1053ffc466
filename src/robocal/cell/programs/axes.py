"""Filter the axis targets of a program for a robot on external axes (issue 34): KRL ``E6AXIS`` with ``E1``..,
RAPID ``jointtarget`` with ``extax``.

A KUKA program for an arm on a track (or a column) holds its joint targets as ``E6AXIS`` aggregates: ``A1``..``A6``
in degrees and the external axes ``E1``.. in mm (the description's prismatic joints, in chain order, are
``E1``, ``E2`` ..). Each target is corrected by :func:`robocal.compensation.axes.compensate_axes` (the calibrated
robot and, when given, its axes' own errors along the travel); the arm's values are written back, and the external
axes' only with ``move_external`` (by default a correction never moves the track: its text is kept as written).
The program is read with :func:`robocal.cell.programs.krl.read_krl` and written with its renderer, so everything
else passes through byte for byte; the filtered files go to another folder, the originals are never written.
An ABB module (:func:`filter_rapid_axes`) the same way: ``jointtarget`` values ``[[robax], [extax]]``, the external
axes ``eax_a``.. in order (mm), read with :func:`robocal.cell.programs.rapid.read_rapid`.

Cartesian targets (``E6POS``, ``robtarget``) of such a robot are refused by name (their inverse kinematics with an
external axis is not built), as are the service and :mod:`robocal.cell.programs.filter` for it (revolute chains
only).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from robocal.calibration.result import CalibrationResult
from robocal.cell.programs.common import ProgramError, apply_edits, format_number
from robocal.cell.programs.krl import read_krl
from robocal.cell.programs.krl import render as render_krl
from robocal.cell.programs.rapid import read_rapid
from robocal.cell.programs.rapid import render as render_rapid
from robocal.compensation.axes import compensate_axes
from robocal.errors import ConfigError


@dataclass(frozen=True)
class AxisFilter:
    """A filtered program: ``texts`` {file name: new text}; ``rows`` one record per target (name, line, the
    external axes before/after, the calibrated model's error before and after, mm)."""

    texts: dict[str, str]
    rows: list[dict[str, Any]]


def filter_krl_axes(
    src: str | Path,
    result: CalibrationResult,
    axis_fit: Any = None,
    move_external: bool = False,
    out_dir: str | Path | None = None,
) -> AxisFilter:
    """Correct every ``E6AXIS`` target of the KRL program ``src`` (module docstring); with ``out_dir`` the
    filtered ``.src``/``.dat`` are written there (it must not be the program's own folder)."""
    return _filter("krl", src, result, axis_fit, move_external, out_dir)


def filter_rapid_axes(
    mod: str | Path,
    result: CalibrationResult,
    axis_fit: Any = None,
    move_external: bool = False,
    out_dir: str | Path | None = None,
) -> AxisFilter:
    """Correct every ``jointtarget`` of the RAPID module ``mod`` (module docstring); with ``out_dir`` the filtered
    module is written there."""
    return _filter("rapid", mod, result, axis_fit, move_external, out_dir)


def _external(dialect: str, t: Any, n_ext: int, names: list[str]) -> list[float]:
    """The external axes' values of an axis target (mm), or a ProgramError naming the one missing."""
    if dialect == "krl":
        out = []
        for i in range(n_ext):
            if f"e{i + 1}" not in t.data["vals"]:
                raise ProgramError(f"target {t.name} lacks E{i + 1} ({names[i]})", t.file, t.line)
            out.append(float(t.data["vals"][f"e{i + 1}"]))
        return out
    node = t.data["node"]
    ext = node.item(1, t.file, t.data["text"], t.name).numbers(t.file, t.data["text"], f"jointtarget {t.name} extax", 6)
    if any(abs(v) >= 9e8 for v in ext[:n_ext]):
        raise ProgramError(f"jointtarget {t.name}: extax has no value (9E9) for {names}", t.file, t.line)
    return ext[:n_ext]


def _render(dialect: str, t: Any, arm_deg: np.ndarray, ext_mm: np.ndarray | None) -> str:
    """The target's text with the arm's new values and (when given) the external axes'."""
    if dialect == "krl":
        vals = dict(t.data["vals"])
        if ext_mm is not None:
            for i, v in enumerate(ext_mm):
                vals[f"e{i + 1}"] = format_number(float(v), 4)
        return render_krl(replace(t, data={**t.data, "vals": vals}), {"q_deg": arm_deg})
    out = render_rapid(t, {"q_deg": arm_deg})
    if ext_mm is None:
        return out
    node, text = t.data["node"], t.data["text"]
    en = node.items[1]
    old = [it.leaf for it in en.items]
    new = [format_number(float(v), 4) for v in ext_mm] + old[len(ext_mm) :]
    rob = (node.items or [])[0]
    shift = len(out) - (node.end - node.start)  # the robax edit changed the length before extax
    a, b = en.start - node.start + shift, en.end - node.start + shift
    assert out[a:b] == text[en.start : en.end]
    return out[:a] + "[" + ",".join(new) + "]" + out[b:] if rob.end <= en.start else out


def _filter(
    dialect: str,
    src: str | Path,
    result: CalibrationResult,
    axis_fit: Any,
    move_external: bool,
    out_dir: str | Path | None,
) -> AxisFilter:
    robot = result.model.robot
    if not robot.has_prismatic:
        raise ConfigError(f"robot {robot.name!r} has no external axis: use robocal filter")
    arm = [j for j in range(robot.n_joints) if not robot.prismatic[j]]
    ext = [j for j in range(robot.n_joints) if robot.prismatic[j]]
    if len(arm) != 6 or len(ext) > 6:
        raise ConfigError(f"{robot.name}: an E6AXIS holds six arm joints and up to six external axes")
    prog = read_krl(src) if dialect == "krl" else read_rapid(src)
    q_rep = np.zeros((len(prog.targets), robot.n_joints))
    for k, t in enumerate(prog.targets):
        if t.kind != "axis":
            raise ProgramError(
                f"target {t.name}: a Cartesian target of a robot on external axes; only axis targets (E6AXIS, "
                "jointtarget) are filtered (their inverse kinematics with an external axis is not built)",
                t.file,
                t.line,
            )
        assert t.q_deg is not None
        q_rep[k, arm] = np.deg2rad(t.q_deg)
        q_rep[k, ext] = _external(dialect, t, len(ext), [robot.joint_names[j] for j in ext])
    q_target = robot.to_kinematic(q_rep)
    comp = compensate_axes(result, q_target, axis_fit=axis_fit, move_external=move_external)
    new_rep = robot.to_reported(comp.q)
    edits: dict[Path, list[tuple[int, int, str]]] = {}
    rows = []
    for k, t in enumerate(prog.targets):
        text = _render(dialect, t, np.rad2deg(new_rep[k, arm]), new_rep[k, ext] if move_external else None)
        edits.setdefault(t.file, []).append((t.span[0], t.span[1], text))
        rows.append(
            {
                "target": t.name,
                "line": t.line,
                **{f"E{i + 1}_before": float(q_rep[k, j]) for i, j in enumerate(ext)},
                **{f"E{i + 1}_after": float(new_rep[k, j]) for i, j in enumerate(ext)},
                "error_before_mm": float(comp.error_before_mm[k]),
                "residual_mm": float(comp.residual_mm[k]),
                "converged": bool(comp.converged[k]),
            }
        )
    texts = {p.name: apply_edits(prog.texts[p], edits.get(p, [])) for p in prog.texts}
    if out_dir is not None:
        out = Path(out_dir)
        if out.resolve() == prog.main.parent.resolve():
            raise ConfigError(f"refusing to overwrite the program in {out}; choose another output folder")
        out.mkdir(parents=True, exist_ok=True)
        for name, text in texts.items():
            (out / name).write_bytes(text.encode("latin-1"))
    return AxisFilter(texts, rows)
