"""Closed loop on the twin: a warm-up driven through the compensation service.

The twin's cell (scenario with the ``thermal`` effect, e.g. ``conf/scenario/thermal.yaml``) is simulated
once to get a calibration campaign and the truth. A bundle is fitted from that campaign (reference
geometric calibration + the proposed thermal model, :mod:`robocal.thermal.fit`) unless one is given.
Then a new warm-up from cold (the validation day's ambient) is driven: every ``interval_min`` the client
reads the simulated temperatures (true curve + sensor noise), asks the service for corrections of
``n_targets`` joint targets, commands the simulated robot (true geometry + true thermal drift) and measures
the tool point with the simulated tracker noise.

Three arms are measured at every epoch against the same desired points (the nominal controller's pose of
each target in the calibrated cell frame ``tracker_T_base · FK_nominal(q) · tool``): *uncompensated*
(the targets as they are), *compensated* (the service's corrected joints) and *oracle* (corrections from
the true model: true geometry and true drift, same Newton). All arms share one noise draw per target and
epoch (a paired comparison: the differences are the models', not the noise's).
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from robocal.errors import ConfigError
from robocal.io import write_json
from robocal.kinematics.ik import compile_chain, forward, solve
from robocal.kinematics.transforms import homogeneous
from robocal.serve.bundle import load_bundle, write_bundle
from robocal.serve.client import Client
from robocal.serve.server import Server, ServerConfig, ServerThread


@dataclass
class ClosedLoopResult:
    t_min: np.ndarray  # (k,)
    errors_mm: dict[str, np.ndarray]  # arm -> (k, n_targets)
    temperatures_C: np.ndarray  # (k, s) as read
    refused: np.ndarray  # (k,) refused targets per epoch
    bundle_dir: Path
    summary: dict[str, Any]


def build_bundle(campaign_dir: Path, robot: Any, out_dir: Path) -> Path:
    """Reference calibration + the proposed thermal model of a warm-up campaign (the thermal pipeline's: the
    parameters selected by the sensitivity screening), written as a bundle."""
    from robocal.data import read_campaign
    from robocal.thermal.fit import ThermalConfig, choose_selected, fit_selected, fit_thermal, run_screening

    camp = read_campaign(campaign_dir, robot)
    fit = fit_thermal(camp, robot, ThermalConfig())
    selected, _ = choose_selected(fit, run_screening(fit, None))
    model, _, _ = fit_selected(fit, selected)
    work = out_dir / "_models"
    cal = write_json(work / "calibration.json", fit.reference.to_dict())
    th = write_json(work / "thermal_model.json", model.to_dict())
    return write_bundle(out_dir / "bundle", robot.name, cal, th)


def well_conditioned_targets(
    robot: Any, chain: Any, tool_T: np.ndarray, n: int, rng: np.random.Generator, ranges_deg: Any = None
) -> np.ndarray:
    """``n`` random joint targets (m, n) rad whose nominal 6x6 joint Jacobian (rotation rows at 1 m) has a
    condition number below 100: away from the singularities, where full-pose compensation is ill-posed."""
    from robocal.sim.scenario import sample_poses

    out: list[np.ndarray] = []
    cc = compile_chain(chain)
    for _ in range(50):
        q = sample_poses(robot, 4 * n, rng, 0.8, ranges_deg)
        p, _, U, O = forward(cc, q, tool_T, record=True)
        assert U is not None and O is not None
        J = np.concatenate([np.cross(U, p[:, :, None] - O, axis=1), 1000.0 * U], axis=1)
        sv = np.linalg.svd(J, compute_uv=False)
        out.extend(q[sv[:, 0] / sv[:, -1] < 100.0])
        if len(out) >= n:
            return np.array(out[:n])
    raise ConfigError(f"could not find {n} well-conditioned targets in the scenario's joint ranges")


def run_closed_loop(
    scenario: str | dict[str, Any] = "thermal",
    out_dir: str | Path = "reports/closed_loop",
    seed: int = 0,
    bundle: str | Path | None = None,
    n_targets: int = 60,
    interval_min: float = 30.0,
    duration_min: float | None = None,
    ratio_bound: float = 1.3,
    service: dict[str, Any] | None = None,
) -> ClosedLoopResult:
    """Drive the warm-up (see the module docstring); writes ``closed_loop.json`` into ``out_dir``.

    service : service settings (as conf/serve/default.yaml ``safety`` / ``solver``); default: the service
    defaults with a 1 degC margin around the fitted temperature range (the validation day starts 0.5 degC
    colder than the calibration day) and a 2 deg correction bound (this twin's full-pose corrections reach ~1.4 deg).
    """
    from robocal.serve.settings import ServiceConfig

    service_config = ServiceConfig.from_mapping(
        service if service is not None else {"safety": {"temperature_margin_C": 1.0, "max_correction_deg": 2.0}}
    )
    from robocal.kinematics.chain import build_chain
    from robocal.robot import load_robot
    from robocal.sim.scenario import load_scenario
    from robocal.sim.thermal import ThermalEffect
    from robocal.sim.twin import simulate

    sc = load_scenario(scenario) if isinstance(scenario, str) else dict(scenario)
    th_cfg = dict((sc.get("effects") or {}).get("thermal") or {})
    if not th_cfg:
        raise ConfigError(
            "the closed loop needs a scenario with the 'thermal' twin effect (conf/scenario/thermal.yaml)"
        )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    robot = load_robot(sc.get("robot", "kr16_2"))
    chain = build_chain(robot)
    with tempfile.TemporaryDirectory() as tmp:
        truth = simulate(sc, Path(tmp) / "campaign", seed=seed, robot=robot)
        bdir = Path(bundle) if bundle is not None else build_bundle(Path(tmp) / "campaign", robot, out)
    b = load_bundle(bdir)
    tname = b.default_tool
    eta_true, T_true, tool_true = _true_cell(truth, chain, tname)
    effect = ThermalEffect(th_cfg)
    effect._setup(SimpleNamespace(robot=robot, chain=chain))  # type: ignore[arg-type]
    states = [float(v) for v in (th_cfg.get("validation_states_min") or th_cfg.get("states_min") or [0, 180])]
    dur = float(duration_min if duration_min is not None else max(states))
    t_grid = np.arange(0.0, dur + 1e-9, float(interval_min))
    rng = np.random.default_rng(seed + 7919)
    tool_id = b.tools[tname]
    q_t = well_conditioned_targets(robot, chain, tool_id, n_targets, rng, sc.get("joint_ranges_deg"))
    # desired points: the nominal controller's tool pose in the calibrated cell frame
    p_des, R_des, _, _ = forward(compile_chain(chain, None, b.tracker_T_base), q_t, tool_id)
    arms = ("uncompensated", "compensated", "oracle")
    errs: dict[str, list[np.ndarray]] = {a: [] for a in arms}
    temps_read, refused = [], []
    accepted: list[np.ndarray] = []
    noise_mm = float(truth.get("noise_mm", 0.015))
    srv = Server(bdir, ServerConfig(port=0), service_config)
    with ServerThread(srv) as st, Client("127.0.0.1", st.port) as client:
        for t in t_grid:
            T_now = effect.temperatures(np.array([t * 60.0]), day=1)[0]
            T_read = T_now + rng.normal(0.0, effect.noise_C, T_now.shape)
            temps_read.append(T_read)
            q_c, ok = _corrected(client, b, q_t, T_read)
            refused.append(int((~ok).sum()))
            accepted.append(ok)
            cc_true = compile_chain(chain, eta_true + effect.drift(T_now[None, :], chain.n_params)[0], T_true)
            oracle = solve(cc_true, tool_true, q_t, p_des, R_des, tol_mm=1e-6)
            noise = rng.normal(0.0, noise_mm, (n_targets, 3))
            for arm, q in (("uncompensated", q_t), ("compensated", q_c), ("oracle", oracle.q)):
                p, _, _, _ = forward(cc_true, q, tool_true)
                errs[arm].append(np.linalg.norm(p + noise - p_des, axis=1))
    # statistics over the targets whose correction was accepted (paired: the same targets in every arm); the
    # refused ones are counted apart, and their errors are NaN in the saved arrays
    ok_all = np.array(accepted)
    E = {a: np.where(ok_all, np.array(v), np.nan) for a, v in errs.items()}
    summary = {
        "scenario": sc.get("name", "custom"),
        "seed": seed,
        "bundle": b.bundle_id,
        "n_targets": n_targets,
        "interval_min": interval_min,
        "t_min": t_grid.tolist(),
        **_error_summary(E, ratio_bound),
        "refused": [int(x) for x in refused],
    }
    write_json(out / "closed_loop.json", summary)
    return ClosedLoopResult(t_grid, E, np.array(temps_read), np.array(refused), bdir, summary)


def _true_cell(truth: dict[str, Any], chain: Any, tname: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The twin's true kinematic errors (P,), tracker frame (4, 4) and the bundle tool's true transform (4, 4)."""
    eta_true = np.array([truth["kinematic_errors"][n] for n in chain.param_names])
    T_true = np.array(truth["tracker_T_base"])
    if tname not in truth["tools_mm"]:
        raise ConfigError(f"bundle tool {tname!r} is not a target of the scenario {list(truth['tools_mm'])}")
    tool_true = homogeneous(np.array(truth["tool_rotations"][tname]), np.array(truth["tools_mm"][tname]))
    return eta_true, T_true, tool_true


def _corrected(client: Client, b: Any, q_t: np.ndarray, T_read: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The joints the cell goes to (m, n) rad, as the service corrects the targets ``q_t`` at the temperature
    reading ``T_read``, and which corrections were accepted (m,); a refused target keeps its joints."""
    reply = client.correct(
        np.rad2deg(q_t),
        temperatures=dict(zip(b.sensors, T_read.tolist(), strict=True)) if b.thermal is not None else None,
    )
    q_c = q_t.copy()
    ok = np.ones(q_t.shape[0], dtype=bool)
    for k, res in enumerate(reply["results"]):
        if res["status"] == "refused":
            ok[k] = False  # a refused correction is never applied (the cell does not go there)
        else:
            q_c[k] = np.deg2rad(res["q_deg"])
    return q_c, ok


def _error_summary(E: dict[str, np.ndarray], ratio_bound: float) -> dict[str, Any]:
    """Mean and max error per arm and time, the overall means, and the compensated-to-oracle ratio against its
    bound (NaN errors, refused targets, left out)."""
    mean = {a: np.nanmean(e, axis=1) for a, e in E.items()}
    ratio = mean["compensated"] / mean["oracle"]
    return {
        "mean_error_mm": {a: m.tolist() for a, m in mean.items()},
        "max_error_mm": {a: np.nanmax(e, axis=1).tolist() for a, e in E.items()},
        "overall_mean_mm": {a: float(np.nanmean(e)) for a, e in E.items()},
        "ratio_compensated_to_oracle": ratio.tolist(),
        "max_ratio": float(ratio.max()),
        "ratio_bound": ratio_bound,
        "within_bound": bool(ratio.max() <= ratio_bound),
    }


def write_report(res: ClosedLoopResult, out_dir: str | Path, tracking: bool = True) -> Path:
    """Plot, HTML report and an MLflow run of a closed-loop result."""
    from robocal.report.html import Report
    from robocal.report.plots import save_figure, time_series
    from robocal.tracking.runs import StageRun

    out = Path(out_dir)
    s = res.summary
    means = {f"{a} (mean)": np.nanmean(res.errors_mm[a], axis=1) for a in res.errors_mm}
    fig = time_series(res.t_min, means, "tool position error (mm)")
    png = save_figure(fig, out / "closed_loop_error.png")
    rep = Report("Closed-loop compensation over a warm-up")
    rep.paragraph(
        f"Scenario {s['scenario']} (seed {s['seed']}), bundle {s['bundle']}; {s['n_targets']} targets every "
        f"{s['interval_min']:g} min, measured with the twin's tracker noise (same draw for every arm)."
    )
    rep.kv(
        {a: f"{v:.4f} mm" for a, v in s["overall_mean_mm"].items()}
        | {
            "max compensated / oracle": f"{s['max_ratio']:.3f} (bound {s['ratio_bound']})",
            "refused corrections": str(sum(s["refused"])),
        }
    )
    rep.figure(fig, "mean tool position error per epoch")
    rows = [
        [f"{t:g}"]
        + [f"{s['mean_error_mm'][a][k]:.4f}" for a in s["mean_error_mm"]]
        + [f"{s['ratio_compensated_to_oracle'][k]:.3f}"]
        for k, t in enumerate(s["t_min"])
    ]
    rep.table(rows, columns=["t (min)", *s["mean_error_mm"], "ratio"])
    html = rep.save(out / "closed_loop.html")
    with StageRun("closed_loop", enabled=tracking) as run:
        run.log_params(
            {"scenario": s["scenario"], "seed": s["seed"], "bundle": s["bundle"], "n_targets": s["n_targets"]}
        )
        for k, t in enumerate(s["t_min"]):
            run.log_metrics({f"{a}_mean_mm": s["mean_error_mm"][a][k] for a in s["mean_error_mm"]}, step=int(t))
        run.log_metrics(
            {"max_ratio": s["max_ratio"], **{f"overall_{a}_mm": v for a, v in s["overall_mean_mm"].items()}}
        )
        run.log_artifact(png)
        run.log_artifact(html)
        run.log_artifact(out / "closed_loop.json")
    return html


def main_summary_line(res: ClosedLoopResult) -> str:
    s = res.summary
    o = s["overall_mean_mm"]
    return (
        f"closed loop: mean error uncompensated {o['uncompensated']:.4f} mm, compensated {o['compensated']:.4f} mm, "
        f"oracle {o['oracle']:.4f} mm; max compensated/oracle {s['max_ratio']:.3f} "
        f"({'within' if s['within_bound'] else 'ABOVE'} {s['ratio_bound']}); refused {sum(s['refused'])}"
    )


__all__ = ["ClosedLoopResult", "build_bundle", "run_closed_loop", "write_report"]
