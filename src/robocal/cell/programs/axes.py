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

Cartesian targets (``E6POS`` with ``E1``.., ``robtarget`` with ``extax``) the same way: the joints the nominal
controller uses are the arm's inverse kinematics with the external axes held at the target's values
(:func:`robocal.cell.programs.filter.nominal_ik` on :func:`robocal.kinematics.axes.arm_chain`: the target's
configuration, Status/Turn or confdata, the solution nearest to the previous target), the correction is
:func:`~robocal.compensation.axes.compensate_axes` on the program's tool, and the target is rewritten with the
nominal pose of the corrected joints in its base frame, the configuration of the corrected arm and (with
``move_external``) the corrected external axes. A target whose correction does not converge (near a singular
pose) keeps its text (``converged`` False in its row).
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
from robocal.kinematics.chain import fk


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
    """The external axes' values of a target (mm): KRL ``E1``.. of an E6AXIS / E6POS, RAPID ``extax`` of a
    jointtarget / robtarget; a ProgramError naming the one missing."""
    if dialect == "krl":
        out = []
        for i in range(n_ext):
            if f"e{i + 1}" not in t.data["vals"]:
                raise ProgramError(f"target {t.name} lacks E{i + 1} ({names[i]})", t.file, t.line)
            out.append(float(t.data["vals"][f"e{i + 1}"]))
        return out
    node, what = t.data["node"], ("robtarget" if t.kind == "pose" else "jointtarget")
    en = node.item(3 if t.kind == "pose" else 1, t.file, t.data["text"], t.name)
    ext = en.numbers(t.file, t.data["text"], f"{what} {t.name} extax", 6)
    if any(abs(v) >= 9e8 for v in ext[:n_ext]):
        raise ProgramError(f"{what} {t.name}: extax has no value (9E9) for {names}", t.file, t.line)
    return ext[:n_ext]


def _render(dialect: str, t: Any, new: dict[str, Any], ext_mm: np.ndarray | None) -> str:
    """The target's text with the new values (``new`` as the dialect's renderer takes them) and, when given, the
    external axes' (mm)."""
    if dialect == "krl":
        vals = dict(t.data["vals"])
        if ext_mm is not None:
            for i, v in enumerate(ext_mm):
                vals[f"e{i + 1}"] = format_number(float(v), 4)
        return render_krl(replace(t, data={**t.data, "vals": vals}), new)
    return render_rapid(t, new if ext_mm is None else {**new, "extax": list(ext_mm)})


def _nominal_joints(dialect: str, prog: Any, robot: Any, q_rep: np.ndarray, arm: list[int], ext: list[int]) -> None:
    """The joints the nominal controller uses for the Cartesian targets, into ``q_rep`` (reported values): the
    arm's inverse kinematics (:func:`robocal.cell.programs.filter.nominal_ik`: the target's configuration, the
    nearest solution to the previous target) with the external axes held at the target's values."""
    from robocal.cell.programs.filter import nominal_ik
    from robocal.kinematics.axes import arm_chain
    from robocal.kinematics.chain import build_chain
    from robocal.kinematics.ik import compile_chain

    if robot.coupling is not None:
        raise ConfigError(f"{robot.name}: Cartesian targets of a coupled robot on external axes are not filtered")
    chain = build_chain(robot)
    cache: dict[bytes, Any] = {}

    def chain_of(k: int) -> Any:
        key = q_rep[k, ext].tobytes()
        if key not in cache:
            cache[key] = compile_chain(arm_chain(chain, ext, q_rep[k, ext]))
        return cache[key]

    q_arm = nominal_ik(prog, None, robot.q_limits[arm], chain_of=chain_of)
    pose = [k for k, t in enumerate(prog.targets) if t.kind == "pose"]
    q_rep[np.ix_(pose, arm)] = q_arm[pose]


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
    names = [robot.joint_names[j] for j in ext]
    for k, t in enumerate(prog.targets):
        if t.kind == "axis":
            assert t.q_deg is not None
            q_rep[k, arm] = np.deg2rad(t.q_deg)
        q_rep[k, ext] = _external(dialect, t, len(ext), names)
    pose = [k for k, t in enumerate(prog.targets) if t.kind == "pose"]
    if pose:
        _nominal_joints(dialect, prog, robot, q_rep, arm, ext)
    q_target = robot.to_kinematic(q_rep)
    q_new = q_target.copy()
    err_b, resid = np.zeros(len(q_rep)), np.zeros(len(q_rep))
    conv = np.zeros(len(q_rep), dtype=bool)
    # axis targets: the calibration's reflector; Cartesian ones: the program's tool (the pose is its TCP's)
    groups: dict[bytes, list[int]] = {}
    for k, t in enumerate(prog.targets):
        groups.setdefault(b"" if t.kind == "axis" else np.asarray(t.tool).tobytes(), []).append(k)
    for key, rows in groups.items():
        tool = None if key == b"" else prog.targets[rows[0]].tool
        comp = compensate_axes(result, q_target[rows], axis_fit=axis_fit, move_external=move_external, tool=tool)
        q_new[rows], conv[rows] = comp.q, comp.converged
        err_b[rows], resid[rows] = comp.error_before_mm, comp.residual_mm
    new_rep = robot.to_reported(q_new)
    edits: dict[Path, list[tuple[int, int, str]]] = {}
    rows_out = []
    for k, t in enumerate(prog.targets):
        if conv[k]:  # a correction that did not converge (near a singular pose) keeps the target as written
            new: dict[str, Any]
            if t.kind == "axis":
                new = {"q_deg": np.rad2deg(new_rep[k, arm])}
            else:
                new = _pose_command(dialect, robot, t, new_rep[k], arm, ext)
            text = _render(dialect, t, new, new_rep[k, ext] if move_external else None)
            edits.setdefault(t.file, []).append((t.span[0], t.span[1], text))
        rows_out.append(
            {
                "target": t.name,
                "kind": t.kind,
                "line": t.line,
                **{f"E{i + 1}_before": float(q_rep[k, j]) for i, j in enumerate(ext)},
                **{f"E{i + 1}_after": float(new_rep[k, j]) for i, j in enumerate(ext)},
                "q_nominal_deg": np.rad2deg(q_rep[k, arm]).tolist(),
                "q_corrected_deg": np.rad2deg(new_rep[k, arm]).tolist(),
                "error_before_mm": float(err_b[k]),
                "residual_mm": float(resid[k]),
                "converged": bool(conv[k]),
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
    return AxisFilter(texts, rows_out)


def _pose_command(dialect: str, robot: Any, t: Any, q: np.ndarray, arm: list[int], ext: list[int]) -> dict[str, Any]:
    """What a Cartesian target is rewritten with: the nominal pose of the corrected joints ``q`` (n,) in the
    target's base frame, and the configuration of the corrected arm (with its external axes there)."""
    from robocal.cell.programs.common import written_config
    from robocal.kinematics.axes import arm_chain
    from robocal.kinematics.chain import build_chain
    from robocal.kinematics.ik import compile_chain
    from robocal.kinematics.transforms import inv_transform

    chain = build_chain(robot)
    T = fk(chain, q[None])[0] @ t.tool
    new: dict[str, Any] = {"T_base_tcp": inv_transform(t.base) @ T}
    new.update(written_config(dialect, compile_chain(arm_chain(chain, ext, q[ext])), q[arm], t.config))
    return new
