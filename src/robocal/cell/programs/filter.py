"""Filter a robot program with a calibration bundle: every target corrected so that the nominal controller lands
where the program meant, with the compensation service's refusals.

For each target (in the order the program moves to them):

1. the joints the nominal controller would use: an axis target as written; a Cartesian target through the
   nominal inverse kinematics (:func:`robocal.kinematics.ik.solve` on the nominal compiled chain), started from the
   previous target's joints, the nearest axis target before it and random starts that agree with the target's
   configuration data, keeping the solutions whose configuration (Status/Turn, confdata) matches the target's
   and that are within the joint limits, the one nearest to the previous target;
2. the pose the program means: the nominal forward kinematics of those joints with the program's tool;
3. the corrected joints: the service's correction (:func:`robocal.compensation.correct.correct_targets`) on the
   calibrated chain (``eta0`` + the thermal drift at the stated temperatures), with the compliance deflection
   at the stated payload and the discovered joint-level effects (a backlash's approach direction is taken from
   the move from the previous target), on the TCP of the calibrated model (the program's tool, or the bundle's
   calibrated tool with ``tcp_from_bundle``);
4. the same refusals as the service, with its defaults (the one policy,
   :class:`robocal.compensation.safety.SafetyPolicy`): joint limits with the margin, correction beyond the
   calibration's own joint-space correction or predicted error after it above the bound, not converged or
   residual above ``max_residual_mm`` (near a singularity), temperatures outside the fitted range. A refused
   target keeps its original text and is listed as refused in the table;
5. the command written back: corrected axis values, or the nominal forward kinematics of the corrected joints
   in the target's base frame with the configuration data of the corrected joints.

A target the nominal controller cannot reach (no inverse kinematics solution with its configuration) is an
error naming the file and line and the configurations (confdata, or KRL Status/Turn) of the solutions found within
the joint limits, and nothing is written.

Limits of the inverse kinematics: it is numerical (a damped least-squares phase from up to 3 x 48 starts, then
the service's Newton), not the controller's closed form, so it finds the solution with the stated configuration
with high probability, not certainty; a target within a fraction of a degree of a singular configuration
boundary (the stretched elbow, the wrist centre on axis 1) may be reported unreachable or solved on the wrong
side. A joint on a quadrant or sign boundary (within :data:`~robocal.cell.programs.common.BOUNDARY_TOL_DEG`)
matches both neighbours and keeps the configuration the target stated when written back. A target without
configuration data (a KRL POS without S/T) takes the solution nearest to the previous target, as the
controller's PTP does. The configuration rules are those of
:mod:`robocal.cell.programs.common`.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from robocal.cell.programs.common import (
    Program,
    ProgramError,
    Target,
    apply_edits,
    config_matches,
    config_seeds,
    written_config,
)
from robocal.errors import ConfigError
from robocal.kinematics.transforms import inv_transform

#: random inverse kinematics starts per Cartesian target (besides the previous target and the nearest axis target)
N_SEEDS = 48


@dataclass
class FilterResult:
    """Per target: status, reasons, joints (deg), correction (deg), predicted error and residual (mm); the new
    texts of the program files; the table as CSV text; notes (e.g. the residual layer not applied outside the
    calibrated region)."""

    program: Program
    status: list[str]
    reasons: list[list[str]]
    q_nominal_deg: np.ndarray
    q_corrected_deg: np.ndarray
    predicted_error_mm: np.ndarray
    residual_mm: np.ndarray
    texts: dict[Path, str]
    table: str
    notes: list[list[str]] = field(default_factory=list)  # per target: where an effect does not apply (not a flag)

    @property
    def n_refused(self) -> int:
        return self.status.count("refused")

    @property
    def n_flagged(self) -> int:
        return self.status.count("flagged")


def read_program(path: str | Path) -> Program:
    """A KRL (``.src``/``.dat``) or RAPID (``.mod``/``.modx``/``.prg``) program by its suffix."""
    p = Path(path)
    suf = p.suffix.lower()
    if suf in (".src", ".dat"):
        from robocal.cell.programs.krl import read_krl

        prog: Program = read_krl(p)
        return prog
    if suf in (".mod", ".modx", ".prg", ".sys"):
        from robocal.cell.programs.rapid import read_rapid

        return read_rapid(p)
    raise ProgramError(f"unknown program type {p.suffix!r}: KRL .src/.dat or RAPID .mod", p)


def nominal_ik(
    prog: Program,
    cc_nom: Any,
    limits: np.ndarray,
    seed: int = 0,
    n_seeds: int = N_SEEDS,
    chain_of: Callable[[int], Any] | None = None,
) -> np.ndarray:
    """Joints (m, n) rad the nominal controller uses for each target (see the module docstring, step 1);
    ``chain_of(k)`` the nominal compiled chain of target ``k`` instead of ``cc_nom`` (an arm on external axes: the
    arm with its axes at the target's values, :func:`robocal.kinematics.axes.arm_chain`)."""
    from robocal.kinematics.ik import forward, solve

    nominal = cc_nom

    rng = np.random.default_rng(seed)
    m, n = len(prog.targets), len(limits)
    q = np.full((m, n), np.nan)
    prev: np.ndarray | None = None
    last_axis: np.ndarray | None = None
    for k, t in enumerate(prog.targets):
        if t.kind == "axis":
            assert t.q_deg is not None
            q[k] = np.deg2rad(t.q_deg[:n])
            prev = last_axis = q[k]
            continue
        assert t.T_base_tcp is not None and t.tool is not None and t.base is not None
        cc_nom = nominal if chain_of is None else chain_of(k)
        T_goal = t.base @ t.T_base_tcp  # robot base -> TCP
        seeds = [s for s in (prev, last_axis) if s is not None]
        found: list[np.ndarray] = []  # solutions within the limits, whatever their configuration (for the error)
        for attempt in range(3):  # more starts when none lands on the stated configuration
            rand = config_seeds(prog.dialect, t.config, limits, rng, n_seeds * 4**attempt)
            S = np.vstack([*(np.asarray(s)[None] for s in seeds), rand])
            ns = len(S)
            S = _damped_ik(cc_nom, t.tool, S, T_goal, iters=80 * (attempt + 1))
            sol = solve(
                cc_nom,
                t.tool,
                S,
                np.tile(T_goal[:3, 3], (ns, 1)),
                np.tile(T_goal[:3, :3], (ns, 1, 1)),
                None,
                max_iter=60,
                tol_mm=1e-7,
                tol_rad=1e-10,
                max_step_rad=0.2,
            )
            qs = sol.q
            within = sol.converged & np.all((qs >= limits[:, 0]) & (qs <= limits[:, 1]), axis=1)
            found.append(qs[within])
            ok = within & config_matches(prog.dialect, cc_nom, qs, t.config)
            if ok.any():
                break
        ref = prev if prev is not None else (last_axis if last_axis is not None else np.mean(limits, axis=1))
        if not ok.any():
            raise ProgramError(
                f"target {t.name} is not reachable by the nominal robot with {_config_text(prog.dialect, t.config)}"
                f" ({_unreachable_why(prog.dialect, cc_nom, np.vstack(found), bool(sol.converged.any()), ref)})",
                t.file,
                t.line,
            )
        cand = qs[ok]
        best = cand[np.argmin(np.abs(cand - ref).sum(axis=1))]
        p, _, _, _ = forward(cc_nom, best[None], t.tool)
        if np.abs(p[0] - T_goal[:3, 3]).max() > 1e-5:
            raise ProgramError(f"target {t.name}: inverse kinematics did not converge", t.file, t.line)
        q[k] = best
        prev = best
    return q


def _config_text(dialect: str, config: dict[str, Any]) -> str:
    """A configuration as the program writes it: RAPID ``confdata [cf1,cf4,cf6,cfx]``, KRL ``S 2, T 35``."""
    if dialect == "rapid" and config.get("cf") is not None:
        return "confdata [" + ",".join(str(int(v)) for v in config["cf"]) + "]"
    parts = [f"{k} {int(config[k])}" for k in ("S", "T") if config.get(k) is not None]
    return ", ".join(parts) if parts else "no configuration"


def _unreachable_why(dialect: str, cc_nom: Any, within: np.ndarray, converged: bool, ref: np.ndarray) -> str:
    """Why a target has no solution, and the configurations that reach it within the joint limits (the one
    nearest to ``ref``, the previous target, first), so that the program can be corrected."""
    if not len(within):
        if converged:
            return "every inverse kinematics solution found is outside the joint limits"
        return "no inverse kinematics solution"
    order = np.argsort(np.abs(within - ref).sum(axis=1), kind="stable")
    texts = list(dict.fromkeys(_config_text(dialect, written_config(dialect, cc_nom, q, {})) for q in within[order]))
    more = f" or {len(texts) - 4} more" if len(texts) > 4 else ""
    return (
        "no solution with the stated configuration within the joint limits; it is reached with "
        + " or ".join(texts[:4])
        + more
        + (" (the nearest first)" if len(texts) > 1 else "")
    )


def _damped_ik(cc: Any, tool: np.ndarray, q0: np.ndarray, T_goal: np.ndarray, iters: int = 80) -> np.ndarray:
    """Global phase of the nominal inverse kinematics: damped least squares from far starts (steps clipped to
    0.3 rad, damping adapted per start); the service's Newton then polishes the result."""
    from robocal.kinematics.ik import forward

    q = np.array(q0, dtype=float)
    m, n = q.shape
    lam = np.full(m, 1e2)
    w_rot = 500.0  # mm per rad

    def err(qq: np.ndarray) -> tuple[np.ndarray, Any, Any, Any]:
        p, R, U, O = forward(cc, qq, tool, record=True)
        E = R @ T_goal[:3, :3].T
        w = 0.5 * np.stack([E[:, 2, 1] - E[:, 1, 2], E[:, 0, 2] - E[:, 2, 0], E[:, 1, 0] - E[:, 0, 1]], axis=1)
        return np.concatenate([p - T_goal[:3, 3], w_rot * w], axis=1), p, U, O

    e, p, U, O = err(q)
    cost = np.einsum("mi,mi->m", e, e)
    for _ in range(iters):
        D = p[:, :, None] - O
        Jp = np.cross(U, D, axis=1)
        J = np.concatenate([Jp, w_rot * U], axis=1)  # (m, 6, n)
        JT = np.swapaxes(J, 1, 2)
        N = JT @ J + lam[:, None, None] * np.eye(n)
        dq = -np.linalg.solve(N, JT @ e[:, :, None])[:, :, 0]
        big = np.abs(dq).max(axis=1, keepdims=True)
        dq *= np.minimum(1.0, 0.3 / np.maximum(big, 1e-300))
        qn = q + dq
        en, pn, Un, On = err(qn)
        cn = np.einsum("mi,mi->m", en, en)
        better = cn < cost
        q[better], e[better], p[better], U[better], O[better], cost[better] = (
            qn[better],
            en[better],
            pn[better],
            Un[better],
            On[better],
            cn[better],
        )
        lam = np.where(better, lam * 0.3, lam * 4.0).clip(1e-6, 1e8)
        if (cost < 1e-8).all():
            break
    return q


def parse_temperatures(spec: list[str] | None, sensors: tuple[str, ...]) -> np.ndarray | None:
    """``["30"]`` (every sensor) or ``["T_j2_C=31", ...]`` (each sensor named) -> (s,) degC; None without sensors."""
    if not sensors:
        if spec:
            raise ConfigError("--temperature given but the bundle has no thermal model")
        return None
    if not spec:
        raise ConfigError(f"the bundle has a thermal model: state the temperature (--temperature) of {list(sensors)}")
    vals: dict[str, float] = {}
    for item in spec:
        try:
            if "=" in item:
                k, v = item.split("=", 1)
                if k not in sensors:
                    raise ConfigError(f"--temperature {item}: unknown sensor {k!r}; known {list(sensors)}")
                vals[k] = float(v)
            else:
                t = float(item)
                vals.update({s: t for s in sensors if s not in vals})
        except ValueError:
            raise ConfigError(f"--temperature {item!r} must be degC or SENSOR=degC") from None
    missing = [s for s in sensors if s not in vals]
    if missing:
        raise ConfigError(f"--temperature lacks sensor(s) {missing}")
    return np.array([vals[s] for s in sensors])


def filter_program(
    prog: Program,
    bundle: Any,
    temperatures: np.ndarray | None = None,
    payload_kg: float = 0.0,
    tcp_from_bundle: str | None = None,
    safety: Any = None,
    solver: Any = None,
    seed: int = 0,
) -> FilterResult:
    """Correct every target of ``prog`` with ``bundle`` (:func:`robocal.serve.bundle.load_bundle`).

    temperatures : (s,) degC of the bundle's thermal sensors (required when it has a thermal model);
    payload_kg : payload for the compliance model and gravity-driven effects; tcp_from_bundle : name of a bundle
    tool whose calibrated pose is the program's TCP on the real robot (otherwise the program's tool is taken
    as exact on the calibrated flange); safety / solver : :class:`robocal.compensation.safety.SafetyPolicy` and
    :class:`robocal.compensation.correct.SolverConfig` (defaults: the service's). The correction and the refusals
    are the service's own code (:func:`robocal.compensation.correct.correct_targets`).
    """
    from robocal.compensation.correct import correct_targets, zero_offsets
    from robocal.compensation.effects import Signals, compose, needs
    from robocal.compensation.safety import SafetyPolicy
    from robocal.kinematics.ik import compile_chain, forward

    sf = safety or SafetyPolicy()
    robot = bundle.robot
    n = robot.n_joints
    limits = robot.q_limits
    m = len(prog.targets)
    eta = bundle.eta0
    reasons_all: list[str] = []
    if bundle.thermal is not None:
        if temperatures is None:
            raise ConfigError(f"the bundle has a thermal model: state the temperatures of {list(bundle.sensors)}")
        eta = bundle.eta_at(temperatures)
        reasons_all.extend(bundle.temperature_reasons(temperatures, sf.temperature_margin_C))
    cc = compile_chain(bundle.chain, eta)
    cc_nom = compile_chain(bundle.chain, np.zeros_like(bundle.eta0))
    q_t = nominal_ik(prog, cc_nom, limits, seed)

    tools_prog = np.array([t.tool for t in prog.targets])
    if tcp_from_bundle is not None:
        if tcp_from_bundle not in bundle.tools:
            raise ConfigError(f"--tcp-from-bundle {tcp_from_bundle!r}: the bundle's tools are {list(bundle.tools)}")
        tools_true = np.repeat(bundle.tools[tcp_from_bundle][None], m, axis=0)
    else:
        tools_true = tools_prog

    effects = bundle.joint_effects()
    miss = needs(effects) - {"direction"}
    if miss:
        raise ConfigError(
            f"the bundle's discovered effects {[e['key'] for e in bundle.effects]} need {sorted(miss)} per target, "
            "which a program does not give"
        )
    # a backlash's approach direction: the move from the previous target
    direction = np.sign(np.diff(np.vstack([q_t[:1], q_t]), axis=0))
    direction[direction == 0] = 1.0
    offsets = compose(effects, Signals(np.full(m, float(payload_kg)), direction=direction))
    c = correct_targets(
        cc, cc_nom, tools_true, tools_prog, q_t, zero_offsets(bundle.chain, eta), offsets, limits,
        robot.joint_names, solver=solver, policy=sf, request_reasons=reasons_all,
    )  # fmt: skip
    q_c = c.q
    err_b = np.linalg.norm(c.error_before_mm, axis=1)
    resid = np.linalg.norm(c.residual_mm, axis=1)
    status, reasons, notes = c.status, c.reasons, c.notes

    # the commands, written back
    from robocal.cell.programs import krl, rapid

    render = krl.render if prog.dialect == "krl" else rapid.render
    edits: dict[Path, list[tuple[int, int, str]]] = {}
    for k, t in enumerate(prog.targets):
        if status[k] == "refused":
            continue
        new: dict[str, Any] = {}
        if t.kind == "axis":
            assert t.q_deg is not None
            qd = t.q_deg.copy()
            qd[:n] = np.rad2deg(q_c[k])
            new["q_deg"] = qd
        else:
            assert t.tool is not None and t.base is not None
            p, R, _, _ = forward(cc_nom, q_c[k][None], t.tool)
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = R[0], p[0]
            new["T_base_tcp"] = inv_transform(t.base) @ T
            new.update(written_config(prog.dialect, cc_nom, q_c[k], t.config))
        edits.setdefault(t.file, []).append((t.span[0], t.span[1], render(t, new)))
    texts = {p: apply_edits(txt, edits.get(p, [])) for p, txt in prog.texts.items()}
    table = _table(prog.targets, robot, status, reasons, q_t, q_c, err_b, resid, notes)
    return FilterResult(prog, status, reasons, np.rad2deg(q_t), np.rad2deg(q_c), err_b, resid, texts, table, notes)


def _table(
    targets: list[Target],
    robot: Any,
    status: list[str],
    reasons: list[list[str]],
    q_t: np.ndarray,
    q_c: np.ndarray,
    err_b: np.ndarray,
    resid: np.ndarray,
    notes: list[list[str]],
) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    n = q_t.shape[1]
    w.writerow(
        [
            "target",
            "kind",
            "file",
            "line",
            "used_at_lines",
            "tool",
            "base",
            "status",
            "predicted_error_mm",
            "residual_mm",
            "max_correction_deg",
            *[f"dq{j + 1}_deg" for j in range(n)],
            *[f"q{j + 1}_nominal_deg" for j in range(n)],
            *[f"q{j + 1}_corrected_deg" for j in range(n)],
            "reasons",
            "notes",
        ]
    )
    dq = np.rad2deg(q_c - q_t)
    for k, t in enumerate(targets):
        w.writerow(
            [
                t.name,
                t.kind,
                t.file.name,
                t.line,
                " ".join(str(ln) for _, ln in t.used_at),
                t.tool_name,
                t.base_name,
                status[k],
                f"{err_b[k]:.6f}",
                f"{resid[k]:.3g}",
                f"{np.abs(dq[k]).max():.6f}",
                *[f"{v:.6f}" for v in dq[k]],
                *[f"{v:.6f}" for v in np.rad2deg(q_t[k])],
                *[f"{v:.6f}" for v in np.rad2deg(q_c[k])],
                "; ".join(reasons[k]),
                "; ".join(notes[k]),
            ]
        )
    return buf.getvalue()


def write_filtered(result: FilterResult, out_dir: str | Path) -> list[Path]:
    """Write the filtered program files (same names) and ``<program>_filter.csv`` into ``out_dir``, which must
    not be the program's folder (the original is never overwritten). Every file is written atomically, after
    everything was computed."""
    import os
    import tempfile

    out = Path(out_dir)
    for p in result.texts:
        if (out / p.name).resolve() == p.resolve():
            raise ConfigError(f"--out {out} would overwrite the original {p}; choose another folder")
    files = {out / p.name: txt.encode("latin-1") for p, txt in result.texts.items()}
    files[out / f"{result.program.main.stem}_filter.csv"] = result.table.encode("utf-8")
    out.mkdir(parents=True, exist_ok=True)
    tmps: list[tuple[Path, Path]] = []
    try:  # every file complete beside its target first, then all renamed (a failure leaves no new file)
        for target, data in files.items():
            fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=out)
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            tmps.append((Path(tmp_name), target))
        for tmp, target in tmps:
            os.replace(tmp, target)
    finally:
        for tmp, _ in tmps:
            tmp.unlink(missing_ok=True)
    return list(files)
