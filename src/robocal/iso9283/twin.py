"""The twin runs an ISO 9283 pose test: ``robocal simulate iso9283 --out DIR [--bundle B]``.

The cell is a twin scenario's (``twin.scenario``, default ``geometric``): the same true robot as
:func:`robocal.sim.twin.simulate` draws for that scenario and seed (same random streams: a calibration of that
scenario's campaign is a calibration of this robot), the same tracker frame, first target and noise.

The test (``test`` settings, the standard's defaults): the five points of the cube
(:func:`robocal.sim.compliance.iso9283_cube_points`; centre and side as ``robocal plan``'s ``iso9283`` volume), each
reached by the nominal controller's inverse kinematics (one configuration per point, from ``twin.seed_q_deg``),
visited in ``cycles`` cycles, each cycle P1..P5 once per approach direction (``-x``: the tool travels along -x of
the base into the pose). Time advances ``interval_s`` per visit.

What the true robot adds on each visit:

- backlash (the scenario's ``backlash`` effect): each joint lags half its band against the direction it turns in
  when the tool travels along the approach direction (the sign of the minimum-norm joint velocity
  ``J⁺ · d`` of the nominal robot at the pose) -- so the approach directions part (vAP);
- gear and compliance effects as the scenario has them (joint offsets, as :mod:`robocal.sim.twin`);
- thermal drift (the scenario's ``thermal`` effect): the warm-up starts with the test; every visit gets the
  parameter drift of its temperatures (dAP);
- the robot's own scatter: ``twin.repeatability_mm`` (1 sigma per base axis), then the tracker noise.

Before the test the tracker measures the reflector while joint 1, then joint 2 turns (``base_circles.csv``): the
tracker's registration to the robot base by axis circles (:mod:`robocal.iso9283.base_frame`). The truth states the
uncalibrated error at the points in two frames: ``uncalibrated_AP_p_mm`` in the twin's own base frame (the frame its
kinematic errors are drawn in: axis 1 tilted, offset and turned in it by the errors of joint 1's parameters) and
``uncalibrated_AP_p_mm_axes`` in the base frame the true robot's axes define (``tracker_T_base_axes``) -- the one a
measurement of the robot can find, and the one the certificate states.

With a bundle (``--bundle``) the same test is run again into ``DIR/after``: every commanded joint target corrected
by the compensation service (:class:`robocal.serve.protocol.Service`, in process: the service's own path, with the
temperatures when the bundle has a thermal model and the joint directions when it has discovered effects) and
executed by the same true robot with the same random draws.
"""

from __future__ import annotations

from collections.abc import Mapping
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from robocal.compensation import ActualRobot
from robocal.errors import ConfigError
from robocal.io import atomic_write, write_json, write_text
from robocal.iso9283.base_frame import FILE as BASE_CIRCLES
from robocal.iso9283.base_frame import axis_frame, fit_circle
from robocal.iso9283.program import cube_joints, joint_directions
from robocal.iso9283.settings import AXES, IsoSettings
from robocal.kinematics.chain import build_chain, propagate
from robocal.kinematics.transforms import homogeneous, matrix_from_rpy, matrix_to_quat, rotvec_to_matrix
from robocal.robot import load_robot
from robocal.sim.compliance import iso9283_cube_points
from robocal.sim.effects import Rows, TwinContext, load_effect_modules
from robocal.sim.scenario import load_scenario, rng_factory

#: twin effects the ISO test reproduces (others would change the test's plan)
SUPPORTED_EFFECTS = ("backlash", "thermal", "gear", "compliance")


def simulate_iso(
    settings: IsoSettings | None = None,
    out_dir: str | Path = "iso_test",
    scenario: Mapping[str, Any] | str | None = None,
    seed: int | None = None,
    bundle: str | Path | None = None,
) -> dict[str, Any]:
    """Write the ISO test campaign (``poses.csv`` + ISO columns, ``truth.json``, ``settings.yaml``) into
    ``out_dir`` and, with ``bundle``, the compensated test into ``out_dir/after``. Returns the truth."""
    st = settings or IsoSettings()
    sc = dict(load_scenario(scenario or st.twin.scenario) if not isinstance(scenario, Mapping) else scenario)
    out = Path(out_dir)
    truth = _run(st, sc, out, seed, None)
    if bundle is not None:
        _run(st, sc, out / "after", seed, Path(bundle))
    return truth


def _run(st: IsoSettings, sc: dict[str, Any], out: Path, seed: int | None, bundle: Path | None) -> dict[str, Any]:
    seed = int(sc.get("seed", 0) if seed is None else seed)
    robot = load_robot(sc.get("robot", "kr16_2"))
    chain = build_chain(robot)
    rng = rng_factory(seed)
    n, P = robot.n_joints, chain.n_params

    eta, T_base, tname, tool, tool_R = _true_cell(sc, chain, rng)
    orientation = bool(sc.get("orientation", False))

    # the test plan: cube points, their joint configurations, the visits
    vol = st.test.volume
    assert vol.center_mm is not None and vol.side_mm is not None
    pts = iso9283_cube_points(np.asarray(vol.center_mm), float(vol.side_mm), st.test.inset)
    nominal = ActualRobot(chain, np.zeros(P), np.eye(4), tool, tool_R)
    q_pts = cube_joints(nominal, robot, pts, st.twin.seed_q_deg)
    labels = [f"P{k + 1}" for k in range(5)]
    appr = list(st.test.approaches)
    N = st.test.cycles
    cyc, ap_i, pt_i = (a.ravel() for a in np.meshgrid(np.arange(N), np.arange(len(appr)), np.arange(5), indexing="ij"))
    m = len(cyc)
    q_cmd = q_pts[pt_i]
    t_s = np.arange(m) * st.test.interval_s
    dirs_pa = joint_directions(nominal, q_pts, [np.asarray(AXES[a]) for a in appr])  # (5, A, n)
    dirs = dirs_pa[pt_i, ap_i]
    rated = st.test.rated_payload_kg
    payload = np.full(m, 0.0 if rated is None else rated * st.test.load_percent / 100.0)

    rows = Rows(
        pose_id=np.array([f"iso_{labels[p]}_{appr[a]}_c{c + 1:02d}" for c, a, p in zip(cyc, ap_i, pt_i, strict=True)]),
        split=np.full(m, "validation", dtype=object),
        target_index=np.zeros(m, dtype=int),
        q_cmd=q_cmd.copy(),
        t_s=t_s,
        payload_kg=payload,
        dq=np.zeros((m, n)),
        deta=np.zeros((m, P)),
        columns={f"dir{j + 1}": dirs[:, j].astype(float) for j in range(n)},
    )
    truth: dict[str, Any] = {
        "scenario": sc.get("name", "custom"),
        "seed": seed,
        "robot": robot.name,
        "kinematic_errors": {nm: float(v) for nm, v in zip(chain.param_names, eta, strict=True)},
        "tracker_T_base": T_base.tolist(),
        "tools_mm": {tname: tool.tolist()},
        "noise_mm": float(sc.get("noise_mm", 0.015)),
    }
    ctx = TwinContext(robot=robot, chain=chain, eta_true=eta, rng_factory=rng, truth=truth)
    bands, thermal = _apply_effects(dict(sc.get("effects") or {}), rows, ctx, dirs, t_s)

    # the compensated test: the service corrects every commanded joint target
    # the commanded pose: the nominal controller's tool pose at the test configuration (base frame)
    s0 = propagate(chain, q_pts, np.zeros(P))
    cmd_p = s0.o + s0.x * tool[0] + s0.y * tool[1] + s0.z * tool[2]
    cmd_R = s0.R @ tool_R
    if bundle is not None:
        cmd_R_rows = cmd_R[pt_i] if orientation else None
        rows.q_cmd = _compensated(bundle, rows, thermal, cmd_p[pt_i], s0.R[pt_i], cmd_R_rows, cyc)
    rows.q_cmd = np.deg2rad(np.round(np.rad2deg(rows.q_cmd), 6))

    # what the true robot attains (base frame), what the tracker reads
    p_base, R_base = _attained(chain, eta, rows, tool, tool_R)
    rep = rng("iso_repeatability")
    p_att = p_base + rep.normal(0.0, st.twin.repeatability_mm, (m, 3))
    R_att = rotvec_to_matrix(rep.normal(0.0, np.deg2rad(st.twin.repeatability_deg), (m, 3))) @ R_base
    noise = rng("noise")
    sigma = truth["noise_mm"]
    p_meas = p_att @ T_base[:3, :3].T + T_base[:3, 3] + noise.normal(0.0, sigma, (m, 3))
    R_meas = T_base[:3, :3] @ R_att
    if orientation:
        sigma_o = np.deg2rad(float(sc.get("noise_deg", 0.005)))
        R_meas = rotvec_to_matrix(noise.normal(0.0, sigma_o, (m, 3))) @ R_meas

    # truth: the uncalibrated robot's error at the points (noise-free barycentre of the first approach)
    first = ap_i == 0
    unc = {labels[k]: float(np.linalg.norm(p_base[first & (pt_i == k)].mean(axis=0) - cmd_p[k])) for k in range(5)}
    circles, T_axes = _base_circles(st, robot, chain, eta, T_base, tool, q_pts[0], rng, sigma)
    B_axes = np.linalg.inv(T_axes)
    p_axes = p_base @ T_base[:3, :3].T + T_base[:3, 3]  # tracker frame, noise-free
    p_axes = p_axes @ B_axes[:3, :3].T + B_axes[:3, 3]  # the base frame the axes define
    unc_axes = {labels[k]: float(np.linalg.norm(p_axes[first & (pt_i == k)].mean(axis=0) - cmd_p[k])) for k in range(5)}
    truth["iso9283"] = {
        "points_mm": pts.tolist(),
        "commanded_mm": cmd_p.tolist(),
        "q_deg": np.rad2deg(q_pts).round(6).tolist(),
        "approaches": appr,
        "joint_directions": {appr[a]: dirs_pa[:, a].astype(int).tolist() for a in range(len(appr))},
        "cycles": N,
        "repeatability_mm": st.twin.repeatability_mm,
        "sigma_per_axis_mm": float(np.hypot(st.twin.repeatability_mm, sigma)),
        "backlash_band_deg": {str(k): v for k, v in bands.items()},
        "thermal": thermal is not None,
        "uncalibrated_AP_p_mm": unc,
        "uncalibrated_AP_p_mm_axes": unc_axes,
        "tracker_T_base_axes": T_axes.tolist(),
        "compensated_by": None if bundle is None else str(bundle),
    }

    _write(out, sc, st, truth, rows, p_meas, R_meas if orientation else None, labels, appr, cyc, ap_i, pt_i,
           cmd_p, cmd_R if orientation else None, tname, thermal, ctx, seed)  # fmt: skip
    write_text(out / BASE_CIRCLES, circles)
    return truth


#: the base registration's circles (``base_circles.csv``): joint 1, then joint 2 turned through +-CIRCLE_HALF_SPAN_DEG
#: about P1's configuration (clipped to the joint's range), a point every CIRCLE_STEP_DEG (a tracker's continuous
#: mode), the other joints standing at P1's. The spans and the number of points set how well the axes are found:
#: with 0.018 mm of scatter per axis, 181 points over 180 deg and 121 over 120 deg put the test points within
#: ~0.005 mm of where the exact axes put them (13 points over 80 deg: ~0.05 mm).
CIRCLE_HALF_SPAN_DEG = (90.0, 60.0)
CIRCLE_STEP_DEG = 1.0


def _base_circles(
    st: IsoSettings,
    robot: Any,
    chain: Any,
    eta: np.ndarray,
    T_base: np.ndarray,
    tool: np.ndarray,
    q0: np.ndarray,
    rng: Any,
    noise_mm: float,
) -> tuple[str, np.ndarray]:
    """``base_circles.csv`` (:mod:`robocal.iso9283.base_frame`): the reflector measured while joint 1, then joint
    2 turns, before the test (cold: the true geometry, the robot's scatter and the tracker's noise); and the
    ``tracker_T_base`` the true robot's axes define (the same construction on the noise-free lines)."""
    lim = robot.q_limits
    n = len(q0)
    qs, axis = [], []
    for a in (0, 1):
        half = CIRCLE_HALF_SPAN_DEG[a]
        k = round(2 * half / CIRCLE_STEP_DEG) + 1
        ang = np.clip(q0[a] + np.deg2rad(np.linspace(-half, half, k)), lim[a, 0], lim[a, 1])
        q = np.tile(q0, (k, 1))
        q[:, a] = ang
        qs.append(np.deg2rad(np.round(np.rad2deg(q), 6)))
        axis += [a + 1] * k
    q_all = np.vstack(qs)
    m = len(q_all)

    def tracker_points(e: np.ndarray) -> np.ndarray:
        s = propagate(chain, q_all, e)
        return (s.o + s.x * tool[0] + s.y * tool[1] + s.z * tool[2]) @ T_base[:3, :3].T + T_base[:3, 3]

    exact = tracker_points(eta)
    g = rng("iso_base_circles")  # a stream of its own: the test's draws stay as they were
    meas = exact + g.normal(0.0, st.twin.repeatability_mm, (m, 3)) + g.normal(0.0, noise_mm, (m, 3))
    ax = np.array(axis)
    # the frame the true axes define, from the noise-free circles (exact lines), and the nominal one
    nom_pts = propagate(chain, q_all, np.zeros(chain.n_params))
    nom = nom_pts.o + nom_pts.x * tool[0] + nom_pts.y * tool[1] + nom_pts.z * tool[2]
    lines, nlines = [], []
    for a in (1, 2):
        c = fit_circle(exact[ax == a], q_all[ax == a, a - 1])
        cn = fit_circle(nom[ax == a], q_all[ax == a, a - 1])
        lines.append((c.centre, c.normal))
        nlines.append((cn.centre, cn.normal))
    w = np.cross(nlines[0][1], nlines[1][1])
    offset = abs(float((nlines[1][0] - nlines[0][0]) @ w / np.linalg.norm(w))) > 1.0
    A_true = axis_frame(lines[0][0], lines[0][1], lines[1][0], lines[1][1], offset)
    A_nom = axis_frame(nlines[0][0], nlines[0][1], nlines[1][0], nlines[1][1], offset)
    head = ["axis", *[f"q{j + 1}_deg" for j in range(n)], "x_mm", "y_mm", "z_mm"]
    lines_csv = [",".join(head)]
    for k in range(m):
        vals = [str(axis[k]), *[f"{v:.6f}" for v in np.rad2deg(q_all[k])], *[f"{v:.6f}" for v in meas[k]]]
        lines_csv.append(",".join(vals))
    return "\n".join(lines_csv) + "\n", A_true @ np.linalg.inv(A_nom)


def _true_cell(
    sc: Mapping[str, Any], chain: Any, rng: Any
) -> tuple[np.ndarray, np.ndarray, str, np.ndarray, np.ndarray]:
    """The true robot and the cell, drawn as :func:`robocal.sim.twin.simulate` draws them (same streams): the
    kinematic errors (P,), the tracker frame's base transform, the first target's name, position (flange frame,
    mm) and rotation."""
    err = dict(sc.get("errors", {}))
    length_sd = float(err.get("length_mm", 0.3))
    angle_sd = np.deg2rad(float(err.get("angle_deg", 0.02)))
    g = rng("geometry")
    eta = np.array([g.normal(0, length_sd if k == "length" else angle_sd) for k in chain.param_kind])
    tr = dict(sc.get("tracker", {}))
    T_base = homogeneous(
        matrix_from_rpy(np.deg2rad(np.asarray(tr.get("rpy_deg", [0.3, -0.5, 135.0]), dtype=float))),
        np.asarray(tr.get("xyz_mm", [2500.0, 1200.0, -350.0]), dtype=float),
    )
    targets = dict(sc.get("targets", {"T1": [0.0, 0.0, 120.0]}))
    tnames = list(targets)
    tool_R_all = rotvec_to_matrix(rng("tool_rot").normal(0, 0.3, (len(tnames), 3)))
    tname = tnames[0]
    return eta, T_base, tname, np.asarray(targets[tname], dtype=float), tool_R_all[0]


def _apply_effects(
    effects: dict[str, Any], rows: Rows, ctx: TwinContext, dirs: np.ndarray, t_s: np.ndarray
) -> tuple[dict[int, float], Any]:
    """Add the scenario's effects to ``rows``: backlash (half its band against the joint's direction), gear and
    compliance (joint offsets), thermal drift (the warm-up starts with the test). Returns the backlash bands per
    joint and the thermal effect (None without)."""
    n, P = ctx.robot.n_joints, ctx.chain.n_params
    unknown = sorted(k for k, v in effects.items() if v not in (None, False) and k not in SUPPORTED_EFFECTS)
    if unknown:
        raise ConfigError(f"the ISO twin reproduces the effects {list(SUPPORTED_EFFECTS)}; the scenario has {unknown}")
    bands: dict[int, float] = {}
    if effects.get("backlash"):
        for jn, band in dict(dict(effects["backlash"]).get("joints", {})).items():
            j = int(jn)
            if not 1 <= j <= n:
                raise ConfigError(f"backlash effect: joint {jn!r} is not a joint number 1..{n}")
            bands[j] = float(band)
            rows.dq[:, j - 1] += dirs[:, j - 1] * np.deg2rad(float(band)) / 2.0
    thermal = None
    if effects.get("thermal") or effects.get("gear") or effects.get("compliance"):
        load_effect_modules()
        from robocal.sim.effects import EFFECTS

        for name in ("gear", "compliance"):
            if effects.get(name):
                EFFECTS[name](dict(effects[name])).apply(rows, ctx)
        if effects.get("thermal"):
            from robocal.sim.thermal import ThermalEffect

            thermal = ThermalEffect(dict(effects["thermal"]))
            thermal._setup(ctx)  # the warm-up starts with the test (day 1's ambient)
            temps = thermal.temperatures(t_s, 0)
            rows.deta += thermal.drift(temps, P)
    return bands, thermal


def _attained(
    chain: Any, eta: np.ndarray, rows: Rows, tool: np.ndarray, tool_R: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The tool pose the true robot attains at every visit (base frame): positions (m, 3) mm, rotations (m, 3, 3);
    one forward kinematics per distinct parameter drift."""
    m = rows.q_cmd.shape[0]
    q_true = rows.q_cmd + rows.dq
    p_base = np.zeros((m, 3))
    R_base = np.zeros((m, 3, 3))
    keys, inv = np.unique(np.round(rows.deta, 15), axis=0, return_inverse=True)
    for gi in range(len(keys)):
        sel = inv.ravel() == gi
        s = propagate(chain, q_true[sel], eta + rows.deta[np.flatnonzero(sel)[0]])
        p_base[sel] = s.o + s.x * tool[0] + s.y * tool[1] + s.z * tool[2]
        R_base[sel] = s.R @ tool_R
    return p_base, R_base


def _compensated(
    bundle: Path,
    rows: Rows,
    thermal: Any,
    cmd_p: np.ndarray,
    flange_R: np.ndarray,
    cmd_R: np.ndarray | None,
    cyc: np.ndarray,
) -> np.ndarray:
    """Every commanded target corrected by the compensation service over ``bundle``: a pose target (the commanded
    position; the commanded orientation when it is one, else the test configuration's flange orientation with the
    bundle's tool), from the test configuration as the seed; ``position`` mode unless the orientation is commanded
    and the bundle's calibration has orientations."""
    from robocal.serve.bundle import load_bundle
    from robocal.serve.protocol import Service
    from robocal.serve.settings import ServiceConfig

    b = load_bundle(bundle)
    # the closed loop's service settings: the test starts cold, at the edge of a thermal model's fitted range
    service = Service(b, ServiceConfig.from_mapping({"safety": {"temperature_margin_C": 1.0}}))
    n = rows.q_cmd.shape[1]
    if b.robot.n_joints != n:
        raise ConfigError(f"the bundle {bundle} is for {b.robot.name}, not this scenario's robot")
    dirs = np.column_stack([rows.columns[f"dir{j + 1}"] for j in range(n)])
    if not b.calibration.model.orientation:
        cmd_R = None  # a position-only calibration knows no tool rotation: the position is compensated
    tool_R = b.tools[b.default_tool][:3, :3]
    quat = matrix_to_quat(flange_R @ tool_R if cmd_R is None else cmd_R)
    groups = [np.arange(len(cyc))] if b.thermal is None else [np.flatnonzero(cyc == c) for c in np.unique(cyc)]
    q = rows.q_cmd.copy()
    for idx in groups:
        req: dict[str, Any] = {"op": "correct", "mode": "position" if cmd_R is None else "pose"}
        tg = []
        for i in idx:
            t: dict[str, Any] = {
                "xyz_mm": cmd_p[i].tolist(),
                "quat_wxyz": quat[i].tolist(),
                "q_seed_deg": np.rad2deg(b.robot.to_reported(rows.q_cmd[i])).tolist(),  # the service's joints
            }
            if b.effects:
                t["dir"] = dirs[i].tolist()
            tg.append(t)
        req["targets"] = tg
        if b.thermal is not None:
            assert thermal is not None, "a bundle with a thermal model needs a scenario with the thermal effect"
            T = thermal.temperatures(rows.t_s[idx[:1]], 0)[0]
            sens = list(thermal.sensors)
            req["temperatures"] = {s: float(T[sens.index(s)]) for s in b.sensors}
        reply = service.handle(req, {})
        for k, r in zip(idx, reply["results"], strict=True):
            if r["status"] == "refused":
                raise ConfigError(f"the service refused ISO target {rows.pose_id[k]}: {r.get('reasons')}")
            q[k] = b.robot.to_kinematic(np.deg2rad(np.asarray(r["q_deg"], dtype=float)))
    return q


def _write(
    out: Path,
    sc: Mapping[str, Any],
    st: IsoSettings,
    truth: dict[str, Any],
    rows: Rows,
    p_meas: np.ndarray,
    R_meas: np.ndarray | None,
    labels: list[str],
    appr: list[str],
    cyc: np.ndarray,
    ap_i: np.ndarray,
    pt_i: np.ndarray,
    cmd_p: np.ndarray,
    cmd_R: np.ndarray | None,
    tname: str,
    thermal: Any,
    ctx: TwinContext,
    seed: int,
) -> None:
    out.mkdir(parents=True, exist_ok=True)
    start = datetime.fromisoformat(str(sc.get("start", "2026-01-05T07:00:00+00:00")).replace("Z", "+00:00"))
    if start.tzinfo is None:
        start = start.replace(tzinfo=UTC)

    def iso(ts: float) -> str:
        return (start + timedelta(seconds=float(ts))).astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"

    def fmt(v: np.ndarray, nd: int) -> list[str]:
        return [f"{x:.{nd}f}" for x in np.asarray(v, dtype=float)]

    n = rows.q_cmd.shape[1]
    head = ["pose_id", "timestamp", "target", *[f"q{j + 1}_deg" for j in range(n)], "x_mm", "y_mm", "z_mm"]
    cols: list[list[str]] = [list(map(str, rows.pose_id)), [iso(t) for t in rows.t_s], [tname] * len(rows.t_s)]
    cols += [fmt(np.rad2deg(rows.q_cmd[:, j]), 6) for j in range(n)]
    cols += [fmt(p_meas[:, c], 6) for c in range(3)]
    if R_meas is not None:
        head += ["qw", "qx", "qy", "qz"]
        quat = matrix_to_quat(R_meas)
        cols += [fmt(quat[:, c], 9) for c in range(4)]
    head.append("payload_kg")
    cols.append(fmt(rows.payload_kg, 3))
    for j in range(n):
        head.append(f"dir{j + 1}")
        cols.append([str(int(x)) for x in rows.columns[f"dir{j + 1}"]])
    head.append("split")
    cols.append(list(map(str, rows.split)))
    head += ["iso_pose", "cycle", "approach", "cmd_x_mm", "cmd_y_mm", "cmd_z_mm"]
    cols += [[labels[k] for k in pt_i], [str(c + 1) for c in cyc], [appr[a] for a in ap_i]]
    cols += [fmt(cmd_p[pt_i, c], 6) for c in range(3)]
    if cmd_R is not None:
        head += ["cmd_qw", "cmd_qx", "cmd_qy", "cmd_qz"]
        cq = matrix_to_quat(cmd_R)
        cols += [fmt(cq[pt_i, c], 9) for c in range(4)]
    lines = [",".join(head)] + [",".join(r) for r in zip(*cols, strict=True)]
    write_text(out / "poses.csv", "\n".join(lines) + "\n")
    if thermal is not None:
        rng = ctx.rng_factory("thermal_sensors")
        t = np.arange(-120.0, float(rows.t_s.max()) + 180.0, 60.0)
        T = thermal.temperatures(t, 0) + rng.normal(0.0, thermal.noise_C, (len(t), len(thermal.sensors)))
        tl = [",".join(["timestamp", *thermal.sensors])]
        tl += [",".join([iso(ts)] + [f"{T[k, c]:.4f}" for c in range(T.shape[1])]) for k, ts in enumerate(t)]
        write_text(out / "temperatures.csv", "\n".join(tl) + "\n")
    else:
        (out / "temperatures.csv").unlink(missing_ok=True)
    write_json(out / "truth.json", truth)
    settings = {"scenario": {**dict(sc), "seed": seed}, "iso9283": _plain(st)}
    atomic_write(out / "settings.yaml", lambda pth: pth.write_text(yaml.safe_dump(settings, sort_keys=True)))


def _plain(obj: Any) -> Any:
    import dataclasses

    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: _plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, tuple | list):
        return [_plain(v) for v in obj]
    return obj


__all__ = ["SUPPORTED_EFFECTS", "simulate_iso"]
