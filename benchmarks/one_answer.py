"""One question, one answer: ``robocal discover`` (CLI), ``robocal.discover`` (Python API) and the pipeline's
``discover`` stage (after ``prepare``) on the same campaign must write the same discovery.json.

    python benchmarks/one_answer.py --data ../shared/data/ur10-ipa            # robot: DATA/robot.yaml
    python benchmarks/one_answer.py --data ../shared/data/abb-irb120 --robot ../shared/data/abb-irb120/robot.yaml

Runs the three in this process (the CLI through its ``main``), writes under ``--out`` (default a temporary
folder) and prints, per path, the rows seen, the named effects and the figures, then whether the three
discovery.json are identical (paths and timings aside: the CLI and API read the user's folder, the stage the
interim copy). Exit 1 when they differ. tests/discovery/test_one_answer.py checks the same on a small twin
campaign.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(REPO / "stages"))


def _paths_aside(obj: object) -> object:
    """discovery.json without what names where the data were read (the user's folder vs the interim copy)."""
    if isinstance(obj, dict):
        return {k: _paths_aside(v) for k, v in obj.items() if k not in ("source", "campaign", "poses_file")}
    if isinstance(obj, list):
        return [_paths_aside(v) for v in obj]
    return obj


def three_ways(data: Path, robot_file: Path, out: Path) -> dict[str, dict]:
    """discovery.json of the CLI, the API and the pipeline stage (each read back), keyed by path."""
    import json

    import robocal
    from robocal.cli import main as cli_main
    from robocal.io import reproducible, write_json
    from robocal.pipeline import compose

    found: dict[str, dict] = {}
    t0 = time.perf_counter()
    with reproducible(True):  # the pipeline's rounding and no timings, for all three
        argv = ["discover", str(data), "--robot", str(robot_file), "--out", str(out / "cli"), "--no-report"]
        assert cli_main(argv) == 0
    found["cli"] = json.loads((out / "cli" / "discovery.json").read_text())
    print(f"cli   {time.perf_counter() - t0:6.0f} s", flush=True)

    t0 = time.perf_counter()
    from robocal.discovery.summary import summary
    from robocal.discovery.validate import validation_errors

    robot = robocal.load_robot(robot_file)
    res = robocal.discover(robocal.read_campaign(data, robot), robot)
    with reproducible(True):
        write_json(out / "api" / "discovery.json", summary(res, validation_errors(res)))
    found["api"] = json.loads((out / "api" / "discovery.json").read_text())
    print(f"api   {time.perf_counter() - t0:6.0f} s", flush=True)

    t0 = time.perf_counter()
    import common
    import discover as discover_stage
    import prepare as prepare_stage

    root = out / "pipeline"
    cfg = compose(REPO, [f"data.campaign={data.resolve()}", f"robot_file={robot_file.resolve()}"])
    cfg["tracking"] = {"enabled": False}
    cfg["discovery"]["report"] = False
    for mod in (prepare_stage, discover_stage):
        st = mod.STAGE
        common.execute(st, mod.compute, cfg, root=root, out=root / st.out, metrics_path=root / st.metrics,
                       plots=None if st.plots is None else root / st.plots)  # fmt: skip
    found["stage"] = json.loads((root / discover_stage.STAGE.out / "discovery.json").read_text())
    print(f"stage {time.perf_counter() - t0:6.0f} s", flush=True)
    return found


def describe(s: dict) -> str:
    named = ", ".join(n["key"] for n in s["named"]) or "nothing"
    val = s.get("validation", {}).get("final", {})
    return (
        f"rows {s['n_rows']} of {s['n_rows_total']} (gross errors {len(s['outliers'])}); named {len(s['named'])}: "
        f"{named}; RMS {s['rms_before_mm']:.4f} -> {s['rms_after_mm']:.4f} mm"
        + (f"; validation mean {val['mean_position_mm']:.4f} mm ({val['n_rows']} rows)" if val else "")
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, type=Path, help="campaign folder")
    ap.add_argument("--robot", type=Path, help="robot YAML (default: DATA/robot.yaml)")
    ap.add_argument("--out", type=Path, help="output folder (default: a temporary one)")
    args = ap.parse_args(argv)
    robot = args.robot or args.data / "robot.yaml"
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        found = three_ways(args.data, robot, out)
    for k, s in found.items():
        print(f"{k:<5} {describe(s)}")
    ref = _paths_aside(found["cli"])
    same = {k: _paths_aside(s) == ref for k, s in found.items()}
    verdict = ", ".join(f"{k} {'yes' if v else 'NO'}" for k, v in same.items())
    print(f"identical discovery.json (paths aside): {verdict}")
    return 0 if all(same.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
