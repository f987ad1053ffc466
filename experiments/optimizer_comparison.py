"""The thermal paper's optimizer comparison (Guo et al. 2026, section 3.2, fig. 4): an experiment, not library code.

Improved GOA vs GOA vs WOA on the geometric calibration: every algorithm x population x run from the same start
(:func:`robocal.calibration.start.calibration_start`), on the calibration as an optimizer Problem
(:func:`robocal.calibration.fit.build_problem`), stopped at an error threshold or an iteration budget.
Run by ``stages/compare_optimizers.py`` (``dvc exp run experiments/dvc.yaml:compare_optimizers``) and by
``benchmarks/compare_paper.py``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.calibration.config import CalibrationConfig
from robocal.calibration.fit import build_problem, calibrate, fit_from, position_config, warm_up
from robocal.calibration.solve import POLISH, solve_at, solve_polish
from robocal.calibration.start import calibration_start
from robocal.config import parse, setting
from robocal.optimizers import make_optimizer, pipeline_options
from robocal.optimizers.registry import registered
from robocal.robot import RobotDescription

if TYPE_CHECKING:
    from robocal.data.campaign import Campaign

POPULATION = registered("population")


def _some(values: tuple[Any, ...]) -> str | None:
    return None if values else "must not be empty"


@dataclass
class CompareSettings:
    """``conf/compare/default.yaml``, validated. ``run``: whether the pipeline's ``compare_optimizers`` stage runs
    the comparison (off by default: it takes minutes; the stage then skips, saying so)."""

    run: bool = False
    algorithms: tuple[str, ...] = setting(("igoa", "goa", "woa"), choices=POPULATION, check=_some)
    populations: tuple[int, ...] = setting((500, 1000, 1500), ge=3, check=_some)
    runs: int = setting(10, ge=1)
    max_iter: int = setting(200, ge=1)
    stop_error: float | str | None = "auto"
    objective: str = "nonlinear"
    bound_mm: float = 1.0
    bound_deg: float = 0.1
    seed: int = 0
    polish: bool = False
    log_history_every: int = 10

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any] | None) -> CompareSettings:
        return parse(cls, cfg, "compare")

    def optimizer_cfg(self, name: str, population: int, coefficients: Mapping[str, Any]) -> dict[str, Any]:
        cfg = {k: v for k, v in coefficients.items() if k not in ("polish", "objective", "max_iter", "population")}
        cfg.update(
            name=name,
            population=population,
            max_iter=self.max_iter,
            polish=self.polish,
            objective=self.objective,
            bound_mm=self.bound_mm,
            bound_deg=self.bound_deg,
            stop_error=self.stop_error,
        )
        return cfg


def compare_optimizers(
    campaign: Campaign,
    robot: RobotDescription,
    cfg: CalibrationConfig,
    settings: CompareSettings,
    coefficients: Mapping[str, Mapping[str, Any]],
    *,
    on_run: Callable[[dict[str, Any], list[float]], None] | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Every algorithm x population x run; returns rows (one per run), convergence histories and the GN reference.

    ``coefficients[name]`` are the optimizer's config entries (``conf/optimizer/<name>.yaml``). Seeds:
    ``settings.seed + run`` (the same seeds for every algorithm and population). ``on_run(row, history)``
    is called after each run (MLflow logging). The "error" of a run is the RMS 3-D position error (mm) of
    the nonlinear model at its best point, whatever the objective; the fitness is reported too.
    """
    start = calibration_start(campaign, robot, position_config(cfg))
    initial = fit_from(start, solve_at(start.x_init))  # the statistics at the start (no iteration)
    gn = calibrate(campaign, robot, replace(position_config(cfg), **POLISH))
    rows: list[dict[str, Any]] = []
    histories: dict[str, list[list[float]]] = {}
    options = pipeline_options(settings.optimizer_cfg(settings.algorithms[0], settings.populations[0], {}))
    problem, search, floor = build_problem(start, options, bounded=True, max_iter=settings.max_iter, seed=0)
    # JIT warm-up, excluded from the timings: compile the kernel, then one iteration of each algorithm
    warmup_s = warm_up(problem)
    for name in settings.algorithms:
        t0 = time.perf_counter()
        ocfg = {**settings.optimizer_cfg(name, min(settings.populations), coefficients.get(name, {})), "max_iter": 1}
        make_optimizer(ocfg).minimize(replace(problem, seed=settings.seed, max_iter=1))
        warmup_s += time.perf_counter() - t0
    from tqdm import tqdm

    total = len(settings.algorithms) * len(settings.populations) * settings.runs
    bar = tqdm(total=total, desc="optimizer comparison", unit="run", disable=not progress, leave=False)
    for name in settings.algorithms:
        for pop in settings.populations:
            ocfg = settings.optimizer_cfg(name, pop, coefficients.get(name, {}))
            opt = make_optimizer(ocfg)
            for run in range(settings.runs):
                bar.set_postfix_str(f"{name} pop {pop} run {run}", refresh=False)
                bar.update(1)
                res = opt.minimize(replace(problem, seed=settings.seed + run))
                rms = search.rms_mm(res.x)
                row = {
                    "algorithm": name,
                    "population": pop,
                    "run": run,
                    "seed": settings.seed + run,
                    "time_s": res.wall_time_s,
                    "nit": res.nit,
                    "nfev": res.nfev,
                    "fitness_mm": res.cost,
                    "error_mm": rms,
                    "reached_stop": res.status == 5,
                }
                if settings.polish:
                    pol = fit_from(start, solve_polish(search.full(res.x)))
                    row["polished_error_mm"] = pol.fit["rms_position_mm"]
                rows.append(row)
                histories.setdefault(f"{name}/{pop}", []).append(list(res.history))
                if on_run is not None:
                    on_run(row, list(res.history))
    bar.close()
    return {
        "rows": rows,
        "histories": histories,
        "gn_rms_mm": gn.fit["rms_position_mm"],
        "gn_time_s": gn.fit["solver_time_s"],
        "jit_warmup_time_s": warmup_s,
        "initial_rms_mm": initial.fit["rms_position_mm"],
        "noise_floor_mm": floor,
        "stop_fitness_mm": problem.target,
        "n_free": int(start.free.size),
        "n_rows": int(start.campaign.n_rows),
    }


def comparison_table(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Mean time, iterations and error per algorithm and population (the paper's fig. 4 quantities)."""
    keys = sorted({(r["algorithm"], r["population"]) for r in rows}, key=lambda k: (k[1], k[0]))
    out = []
    for alg, pop in keys:
        sel = [r for r in rows if r["algorithm"] == alg and r["population"] == pop]
        out.append(
            {
                "algorithm": alg,
                "population": pop,
                "runs": len(sel),
                "time_s": float(np.mean([r["time_s"] for r in sel])),
                "nit": float(np.mean([r["nit"] for r in sel])),
                "error_mm": float(np.mean([r["error_mm"] for r in sel])),
                "error_sd_mm": float(np.std([r["error_mm"] for r in sel])),
                "reached_stop": int(sum(r["reached_stop"] for r in sel)),
                **(
                    {"polished_error_mm": float(np.mean([r["polished_error_mm"] for r in sel]))}
                    if "polished_error_mm" in sel[0]
                    else {}
                ),
            }
        )
    return out


def paper_deltas(table: list[dict[str, Any]], reference: str = "igoa") -> dict[str, dict[str, float]]:
    """Mean over populations of the reference's relative change vs each other algorithm, in % (the paper's way)."""
    out: dict[str, dict[str, float]] = {}
    by = {(r["algorithm"], r["population"]): r for r in table}
    pops = sorted({r["population"] for r in table})
    others = sorted({r["algorithm"] for r in table} - {reference})
    for other in others:
        d: dict[str, list[float]] = {"time_s": [], "nit": [], "error_mm": []}
        for p in pops:
            a, b = by.get((reference, p)), by.get((other, p))
            if a is None or b is None:
                continue
            for k in d:
                if b[k] > 0:
                    d[k].append(100.0 * (a[k] - b[k]) / b[k])
        out[other] = {k: float(np.mean(v)) if v else float("nan") for k, v in d.items()}
    return out


#: The thermal paper's claims (section 3.2): improved GOA relative to GOA and to WOA, mean over populations, %.
PAPER_DELTAS = {
    "goa": {"time_s": -25.00, "nit": -66.50, "error_mm": -21.12},
    "woa": {"time_s": -44.86, "nit": -80.46, "error_mm": -38.80},
}


def write_comparison(result: dict[str, Any], settings: CompareSettings, out_dir: Any) -> dict[str, Any]:
    """Write runs.csv, table.csv and summary.json into ``out_dir``; return the summary."""
    from pathlib import Path

    import pandas as pd

    from robocal.io import atomic_write, write_json

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    table = comparison_table(result["rows"])
    deltas = paper_deltas(table) if "igoa" in settings.algorithms else {}
    runs = pd.DataFrame(result["rows"])
    atomic_write(out / "runs.csv", lambda p: runs.to_csv(p, index=False, float_format="%.6g"))
    atomic_write(out / "table.csv", lambda p: pd.DataFrame(table).to_csv(p, index=False, float_format="%.6g"))
    summary = {
        "settings": {k: (list(v) if isinstance(v, tuple) else v) for k, v in settings.__dict__.items()},
        "table": table,
        "deltas": deltas,
        "paper_deltas": {k: v for k, v in PAPER_DELTAS.items() if k in deltas},
        **{k: result[k] for k in ("gn_rms_mm", "gn_time_s", "initial_rms_mm", "noise_floor_mm", "stop_fitness_mm")},
        "n_free": result["n_free"],
        "n_rows": result["n_rows"],
    }
    write_json(out / "summary.json", summary)
    return summary


def comparison_figures(result: dict[str, Any], summary: dict[str, Any]) -> dict[str, Any]:
    """Fig.-4-like plots: convergence curves per population, bars of time / iterations / error."""
    from robocal.report import plots

    figs: dict[str, Any] = {}
    pops = sorted({r["population"] for r in summary["table"]})
    algs = list(dict.fromkeys(r["algorithm"] for r in summary["table"]))
    for pop in pops:
        hist = {a: result["histories"][f"{a}/{pop}"] for a in algs if result["histories"].get(f"{a}/{pop}")}
        hist = {a: [h for h in runs if h] for a, runs in hist.items()}
        hist = {a: runs for a, runs in hist.items() if runs}
        if hist:
            figs[f"convergence_{pop}"] = plots.convergence(hist, ylabel="best fitness (mm)")
    by = {(r["algorithm"], r["population"]): r for r in summary["table"]}
    labels = [str(p) for p in pops]
    for key, ylabel in (("time_s", "mean time (s)"), ("nit", "mean iterations"), ("error_mm", "mean RMS error (mm)")):
        values = {a: [by[(a, p)][key] if (a, p) in by else np.nan for p in pops] for a in algs}
        figs[f"bars_{key}"] = plots.bar_table(labels, values, ylabel)
    return figs


def comparison_report(result: dict[str, Any], summary: dict[str, Any], settings: CompareSettings) -> Any:
    """The HTML report of the comparison."""
    from robocal.report.html import Report

    rep = Report("Optimizer comparison", "improved GOA vs GOA vs WOA (thermal paper, section 3.2, fig. 4)")
    rep.paragraph(
        f"{summary['n_rows']} calibration poses, {summary['n_free']} free (identifiable) parameters searched within "
        f"±{settings.bound_mm} mm / ±{settings.bound_deg}° of the initial estimate; {settings.runs} independent runs "
        f"per algorithm and population, at most {settings.max_iter} iterations, objective {settings.objective!r}."
    )
    rep.kv(
        {
            "initial RMS error (mm)": summary["initial_rms_mm"],
            "Gauss-Newton RMS error (mm)": summary["gn_rms_mm"],
            "Gauss-Newton solver time (s)": summary["gn_time_s"],
            "noise floor of the fitness (mm)": summary["noise_floor_mm"],
            "stop threshold on the fitness (mm)": summary["stop_fitness_mm"],
        },
        caption="Reference",
    )
    rep.note(
        "Times exclude the just-in-time compilation of the fitness kernel (numba): one warm-up evaluation and one "
        "iteration of each algorithm run before the timed runs. "
        "The paper stops at 'error < 0.01'. As an RMS 3-D error in mm that lies below the noise floor and no method "
        "can reach it; 'auto' stops at 1.1 x the floor instead. The error column is the RMS 3-D position error of the "
        "nonlinear model at each run's best point (mm); it is the raw result of the method, without any polish."
    )
    rep.heading("Mean per algorithm and population")
    rep.table(summary["table"])
    if summary["deltas"]:
        rep.heading("Improved GOA relative to the others (mean over populations, %) beside the paper's claims")
        rows = []
        for other, d in summary["deltas"].items():
            paper = summary["paper_deltas"].get(other, {})
            for k in ("time_s", "nit", "error_mm"):
                rows.append({"vs": other, "quantity": k, "measured_%": d[k], "paper_%": paper.get(k)})
        rep.table(rows)
    rep.heading("Figures")
    for name, fig in comparison_figures(result, summary).items():
        rep.figure(fig, caption=name.replace("_", " "))
    return rep
