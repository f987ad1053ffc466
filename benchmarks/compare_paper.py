"""The thermal paper's optimizer comparison (section 3.2, fig. 4) on the twin, printed beside the paper's claims.

    python benchmarks/compare_paper.py [--runs 10] [--populations 500 1000 1500] [--max-iter 200]
                                       [--stop auto|<mm>|none] [--objective nonlinear|linearized] [--out DIR]

Same code as ``stages/compare_optimizers.py`` (experiments/optimizer_comparison.py) on a fresh
twin campaign (KR16-2 geometric scenario, 100 poses by default), without MLflow; writes the HTML report and
CSV tables to ``--out`` (default reports/benchmarks/compare_paper).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import yaml

from robocal.calibration.config import CalibrationConfig
from robocal.data.contract import read_campaign
from robocal.robot import load_robot
from robocal.sim.scenario import load_scenario
from robocal.sim.twin import simulate

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "experiments"))  # the experiment's code (experiments/optimizer_comparison.py)

from optimizer_comparison import (  # noqa: E402
    CompareSettings,
    compare_optimizers,
    comparison_report,
    write_comparison,
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--populations", type=int, nargs="+", default=[500, 1000, 1500])
    ap.add_argument("--max-iter", type=int, default=200)
    ap.add_argument("--stop", default="auto", help="auto (1.1 x noise floor), a number in mm, or none")
    ap.add_argument("--objective", default="nonlinear", choices=["nonlinear", "linearized"])
    ap.add_argument("--poses", type=int, default=100)
    ap.add_argument("--seed", type=int, default=1, help="twin seed")
    ap.add_argument("--out", default=str(ROOT / "reports" / "benchmarks" / "compare_paper"))
    args = ap.parse_args()
    stop: float | str | None = None if args.stop == "none" else (args.stop if args.stop == "auto" else float(args.stop))
    settings = CompareSettings.from_mapping(
        {
            "runs": args.runs,
            "populations": args.populations,
            "max_iter": args.max_iter,
            "stop_error": stop,
            "objective": args.objective,
        }
    )
    robot = load_robot("kr16_2")
    sc = load_scenario("geometric")
    sc.update(n_poses=args.poses, n_validation_poses=0)
    with tempfile.TemporaryDirectory() as d:
        simulate(sc, d, seed=args.seed)
        camp = read_campaign(d, robot)
    coefficients = {
        name: yaml.safe_load((ROOT / "conf" / "optimizer" / f"{name}.yaml").read_text()) for name in settings.algorithms
    }

    def progress(row: dict, history: list[float]) -> None:
        print(
            f"  {row['algorithm']:5s} pop {row['population']:5d} run {row['run']:2d}: {row['time_s']:6.2f} s, "
            f"{row['nit']:3d} it, error {row['error_mm']:.4f} mm",
            flush=True,
        )

    result = compare_optimizers(camp, robot, CalibrationConfig(), settings, coefficients, on_run=progress)
    summary = write_comparison(result, settings, args.out)
    comparison_report(result, summary, settings).save(Path(args.out) / "report.html")
    print(
        f"\nGauss-Newton RMS {summary['gn_rms_mm']:.4f} mm in {summary['gn_time_s'] * 1e3:.1f} ms; noise floor "
        f"{summary['noise_floor_mm']:.4f} mm; stop below {summary['stop_fitness_mm']}; "
        f"initial {summary['initial_rms_mm']:.3f} mm"
    )
    print(f"\n{'alg':5s} {'pop':>5s} {'time s':>8s} {'iters':>7s} {'error mm':>9s} {'sd':>7s} {'stopped':>7s}")
    for r in summary["table"]:
        print(
            f"{r['algorithm']:5s} {r['population']:5d} {r['time_s']:8.2f} {r['nit']:7.1f} {r['error_mm']:9.4f} "
            f"{r['error_sd_mm']:7.4f} {r['reached_stop']:4d}/{r['runs']}"
        )
    print("\nimproved GOA relative to ... (mean over populations), measured vs paper:")
    for other, d in summary["deltas"].items():
        paper = summary["paper_deltas"].get(other, {})
        print(
            "  vs "
            + other
            + ": "
            + ", ".join(
                f"{k} {d[k]:+.1f} % (paper {paper.get(k, float('nan')):+.2f} %)" for k in ("time_s", "nit", "error_mm")
            )
        )
    print(f"\nreport: {Path(args.out) / 'report.html'}")


if __name__ == "__main__":
    main()
