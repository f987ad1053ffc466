"""End to end: a tiny `dvc repro` in a temporary copy of the repository.

The copy holds what DVC needs (dvc.yaml, params.yaml, conf/, stages/, src/ as deps, .dvc/config,
.dvcignore) in a fresh git repository; robocal itself is imported from the virtual environment. The scenarios
are made tiny in the copy's conf/ (12 + 6 poses) and the plan cheap (2000 candidates), and params.yaml is
regenerated from it, so `dvc exp run` (which recomposes params.yaml from conf/) keeps them so. These tests check
the pipeline's wiring, not its figures: the figures are the library's tests'. MLflow records into a SQLite file
inside the copy. One `dvc repro` of the default pipeline (the module's fixture) is shared by every test; a test
that changes a setting reruns only the stages that setting concerns.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from robocal.pipeline import params_text, write_params

REPO = Path(__file__).resolve().parents[2]
#: every stage of dvc.yaml (the default campaign is the thermal warm-up: all of them have work to do)
STAGES = list(yaml.safe_load((REPO / "dvc.yaml").read_text())["stages"])
#: each stage's output folder (its only `outs:` entry)
OUT = {name: s["outs"][0] for name, s in yaml.safe_load((REPO / "dvc.yaml").read_text())["stages"].items()}
pytestmark = [pytest.mark.slow, pytest.mark.e2e]


def _git(root: Path, *args: str) -> None:
    subprocess.run(
        ["git", "-c", "user.name=robocal-test", "-c", "user.email=test@robocal.invalid", *args],
        cwd=root,
        check=True,
        capture_output=True,
    )


def _reproduce(root: Path, **kwargs: Any) -> list[str]:
    from contextlib import chdir

    from dvc.repo import Repo

    # DVC resolves its default target (dvc.yaml) against the working directory, not the repo root
    with chdir(root), Repo(str(root)) as repo:
        return [s.addressing for s in repo.reproduce(**kwargs)]


def _runs(uri: str, filter_string: str = "") -> list[Any]:
    from mlflow.tracking import MlflowClient

    from robocal.tracking import flush, pending_dir

    flush(uri=uri)  # the stages' runs are written by detached flushers: wait for them
    assert not [d for d in pending_dir(uri).glob("*") if d.is_dir()], "pending runs left unwritten"

    client = MlflowClient(uri)
    exp = client.get_experiment_by_name("robocal")
    assert exp is not None, "no MLflow experiment 'robocal'"
    return list(client.search_runs([exp.experiment_id], filter_string=filter_string, max_results=1000))


@pytest.fixture(scope="module")
def copy(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    root = tmp_path_factory.mktemp("repo")
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")
    for d in ("conf", "stages", "src", "experiments"):
        shutil.copytree(REPO / d, root / d, ignore=ignore)
    # every dvc.yaml of the repository: `dvc status` / `checkout` / `exp run` look at them all
    dvcfiles = [p.relative_to(REPO) for p in REPO.glob("*/dvc.yaml") if p.parts[-2] not in (".venv", "reports")]
    for f in ("dvc.yaml", ".dvcignore", ".dvc/config", *map(str, dvcfiles)):
        (root / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / f, root / f)
    (root / ".gitignore").write_text("/mlflow.db\n/mlartifacts/\n/mlflow-pending/\n/reports/sweeps/\n/reports/runs/\n")
    # a tiny default scenario, in conf/ so that `dvc exp run` keeps it (12 + 6 poses at each of the 7 states),
    # and a tiny geometric one (12 + 6 poses) for the campaign without temperatures
    default = yaml.safe_load((REPO / "conf" / "config.yaml").read_text())["defaults"]
    assert {"scenario": "thermal"} in default
    for name in ("thermal", "geometric"):
        sc = root / "conf" / "scenario" / f"{name}.yaml"
        text = sc.read_text()
        for key, value in (("n_poses", 12), ("n_validation_poses", 6)):
            lines = [ln for ln in text.splitlines() if ln.startswith(f"{key}:")]
            assert len(lines) == 1, key
            text = text.replace(lines[0], f"{key}: {value}")
        sc.write_text(text)
    # the plan draws 2000 candidate poses instead of 20000 (the design of 12 poses stays well conditioned)
    plan = root / "conf" / "plan" / "default.yaml"
    lines = [ln for ln in plan.read_text().splitlines() if ln.startswith("n_candidates:")]
    assert len(lines) == 1
    plan.write_text(plan.read_text().replace(lines[0], "n_candidates: 2000"))
    write_params(root)
    _git(root, "init", "-q")

    uri = f"sqlite:///{root / 'mlflow.db'}"
    mp = pytest.MonkeyPatch()
    mp.setenv("MLFLOW_TRACKING_URI", uri)
    mp.setenv("PATH", f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    mp.setenv("DVC_NO_ANALYTICS", "1")
    mp.setenv("MLFLOW_DISABLE_TELEMETRY", "1")
    mp.delenv("DVC_ROOT", raising=False)
    t0 = time.perf_counter()
    ran = _reproduce(root)
    seconds = time.perf_counter() - t0
    print(f"\ntiny dvc repro (3 stages): {seconds:.1f} s")
    try:
        yield {"root": root, "uri": uri, "ran": ran, "seconds": seconds}
    finally:
        mp.undo()


def test_same_config_same_bytes(copy: dict[str, Any]) -> None:
    """A stage run twice on the same inputs and config writes the same bytes (no timings, rounded floats,
    seeded randomness, plots without dates): what keeps dvc.lock and git clean after `make run`."""
    root = copy["root"]
    outs = ["reports/geometric", "reports/plots/geometric_fit", "reports/metrics/geometric_fit.json"]

    def snapshot() -> dict[str, bytes]:
        files = [f for o in outs for f in ([root / o] if (root / o).is_file() else sorted((root / o).rglob("*")))]
        return {str(f.relative_to(root)): f.read_bytes() for f in files if f.is_file()}

    first = snapshot()
    res = subprocess.run(
        [sys.executable, "stages/geometric_fit.py"], cwd=root, capture_output=True, text=True, timeout=180
    )
    assert res.returncode == 0, res.stderr[-3000:]
    second = snapshot()
    assert sorted(first) == sorted(second)
    changed = [name for name in first if first[name] != second[name]]
    assert not changed, f"not the same bytes on a second run: {changed}"
    assert b"wall_time_s" not in first["reports/metrics/geometric_fit.json"]


def test_outputs_follow_the_umask(copy: dict[str, Any]) -> None:
    """Outputs are created like any open() file (0o666 less the umask), not 0o600 as a temporary file is."""
    mask = os.umask(0)
    os.umask(mask)
    want = 0o666 & ~mask
    for rel in ("reports/metrics/geometric_fit.json", "reports/geometric/report.html", "data/interim/poses.parquet"):
        assert ((copy["root"] / rel).stat().st_mode & 0o777) == want, rel


def test_first_repro_runs_every_stage(copy: dict[str, Any]) -> None:
    root = copy["root"]
    ran = copy["ran"]
    assert sorted(ran) == sorted(STAGES)
    assert ran.index("simulate") < ran.index("prepare") < ran.index("geometric_fit")
    assert ran.index("thermal_fit") < ran.index("screen") < ran.index("validate")
    status = {s: json.loads((root / f"reports/metrics/{s}.json").read_text())[s] for s in STAGES}
    # the warm-up has temperatures but no payload: compliance_fit has nothing to do; the optimizer comparison is
    # off by default
    # and the campaign is not an ISO 9283 test: iso9283 skips, saying so
    assert status == {
        s: ("skipped" if s in ("compliance_fit", "compare_optimizers", "iso9283") else "ok") for s in STAGES
    }
    val = json.loads((root / "reports/metrics/validate.json").read_text())
    assert val["comp_proposed_mean_mm"] < val["comp_none_mean_mm"], val
    # headline metrics only: a few numbers per stage, the full set beside the stage's outputs
    for stage in STAGES:
        assert len(json.loads((root / f"reports/metrics/{stage}.json").read_text())) <= 4, stage
    full = json.loads((root / "reports/validate/all_metrics.json").read_text())
    assert full["validation"]["proposed"]["mean_position_mm"] == pytest.approx(val["comp_proposed_mean_mm"], rel=1e-8)
    # a skipped stage explains itself in its plots folder (an empty one makes DVC warn)
    assert "no payload" in (root / "reports/plots/compliance_fit/skipped.svg").read_text()
    prep = json.loads((root / "data/interim/prepare.json").read_text())
    assert prep["n_rows"] == (12 + 6) * 7 and prep["has_temperatures"] is True
    assert (root / "data/interim/poses.parquet").is_file()
    report = (root / "reports/geometric/report.html").read_text()
    assert "<img" in report and "http://" not in report.split("<body", 1)[-1][:200_000].replace("http://www.w3", "")
    m = json.loads((root / "reports/metrics/geometric_fit.json").read_text())
    assert m["geometric_fit"] == "ok" and 0 < m["fit_rms_mm"] < 0.1
    assert m["val_mean_mm"] < m["val_nominal_mean_mm"]
    assert sorted(p.name for p in (root / "reports/plots/geometric_fit").iterdir()) == [
        "error_histogram.svg",
        "error_per_pose.png",
    ]


def test_every_pipeline_report_reads_clean(copy: dict[str, Any]) -> None:
    """Issue 23, item 12: no page the pipeline writes shows a Python repr, nan / True / False, or text wider than
    the page (headless Chromium at 1000 px where installed). The commands' pages: tests/report/test_pages.py."""
    from robocal.report.html import layout_problems, page_problems

    pages = sorted((copy["root"] / "reports").glob("*/report.html"))
    assert {p.parent.name for p in pages} >= {"plan", "geometric", "thermal", "screen", "validate", "discovery"}
    for page in pages:
        problems = page_problems(page.read_text(encoding="utf-8"))
        assert not problems, f"{page.parent.name}:\n" + "\n".join(problems[:10])
    layout = layout_problems(pages)
    if layout is not None:
        wide = {Path(p).parent.name: v for p, v in layout.items() if v}
        assert not wide, wide


def test_second_repro_runs_nothing(copy: dict[str, Any]) -> None:
    assert _reproduce(copy["root"]) == []


def _dvc(root: Path, *args: str) -> str:
    res = subprocess.run(["dvc", *args], cwd=root, capture_output=True, text=True, timeout=180)
    assert res.returncode == 0, f"dvc {' '.join(args)}: {res.stdout[-2000:]}{res.stderr[-2000:]}"
    return res.stdout + res.stderr


def test_dvc_has_nothing_to_say_after_a_clean_run(copy: dict[str, Any]) -> None:
    """Issue 23, item 10: after a clean `dvc repro` (make run), `dvc status` says the pipeline is up to date and
    `dvc checkout` succeeds without a warning (no stage without a lock entry, no output without hash info)."""
    root = copy["root"]
    status = _dvc(root, "status")
    assert status.strip() == "Data and pipelines are up to date.", status
    checkout = _dvc(root, "checkout")
    assert "WARNING" not in checkout and "ERROR" not in checkout, checkout


def test_one_optimizer_parameter_reruns_only_downstream(copy: dict[str, Any]) -> None:
    root = copy["root"]
    params = root / "params.yaml"
    text = params.read_text()
    old = "optimizer:\n  name: lm\n  max_iter: 100\n"
    assert old in text
    params.write_text(text.replace(old, "optimizer:\n  name: lm\n  max_iter: 50\n"))
    ran = _reproduce(root)
    # the geometric fit and what reads its result; not the twin, the data door or the thermal chain
    assert ran[0] == "geometric_fit" and set(ran) <= {"geometric_fit", "discover"}, ran
    assert _reproduce(root) == []


def test_mlflow_holds_a_run_per_stage_with_metrics(copy: dict[str, Any]) -> None:
    for stage in STAGES:
        runs = [
            r
            for r in _runs(copy["uri"], f"tags.`robocal.stage` = '{stage}'")
            if "mlflow.parentRunId" not in r.data.tags
        ]
        assert runs, stage
        run = runs[0]
        # a skipped stage (no payload; the comparison is off) ends FINISHED (not a red failure), named and tagged so
        skipped = stage in ("compliance_fit", "compare_optimizers", "iso9283")
        assert run.info.status == "FINISHED", stage
        assert run.data.tags.get("robocal.status") == ("skipped" if skipped else "ok"), stage
        assert run.info.run_name == f"{stage}{' (skipped)' if skipped else ''} · twin thermal · workspace"
        assert "wall_time_s" in run.data.metrics, stage
        assert run.data.tags.get("dvc.stage") == stage
    fit = _runs(copy["uri"], "tags.`robocal.stage` = 'geometric_fit'")
    assert len(fit) == 3  # the first repro, the same-bytes rerun and the max_iter change
    newest = fit[0]
    for key in ("fit.rms_position_mm", "validation.mean_position_mm", "validation.max_position_mm", "fit.chi2"):
        assert key in newest.data.metrics, key
    assert newest.data.params["optimizer.max_iter"] == "50"
    # every run's parameters, also keys outside MLflow's charset (the twin's T_j6_C^2 monomial)
    (sim,) = _runs(copy["uri"], "tags.`robocal.stage` = 'simulate'")
    assert sim.data.params["scenario.effects.thermal.drift.theta6.terms_deg.T_j6_C_pow2"] == "0.00015"
    from mlflow.tracking import MlflowClient

    names = {a.path for a in MlflowClient(copy["uri"]).list_artifacts(newest.info.run_id)}
    assert {"report.html", "plots", "params.yaml", "geometric_fit.json"} <= names


def test_hydra_sweep_gives_three_comparable_nested_runs(copy: dict[str, Any]) -> None:
    root = copy["root"]
    cmd = [
        sys.executable,
        "stages/geometric_fit.py",
        "-m",
        "calibration.noise_mm=0.01,0.015,0.02",
        "hydra/launcher=joblib",
        "hydra.launcher.n_jobs=2",
    ]
    res = subprocess.run(cmd, cwd=root, capture_output=True, text=True, timeout=180)
    assert res.returncode == 0, res.stderr[-3000:]
    parents = _runs(copy["uri"], "tags.`robocal.sweep` = 'parent'")
    assert len(parents) == 1 and parents[0].info.status == "FINISHED"
    children = _runs(copy["uri"], f"tags.`mlflow.parentRunId` = '{parents[0].info.run_id}'")
    assert len(children) == 3
    assert sorted(float(r.data.params["calibration.noise_mm"]) for r in children) == [0.01, 0.015, 0.02]
    keys = [set(r.data.metrics) for r in children]
    assert keys[0] == keys[1] == keys[2] and "fit.rms_position_mm" in keys[0]  # comparable side by side
    # chi² scales as 1/noise²: the three runs differ where they should
    chi2 = {float(r.data.params["calibration.noise_mm"]): r.data.metrics["fit.chi2"] for r in children}
    assert chi2[0.01] > chi2[0.015] > chi2[0.02]
    jobs = sorted((root / "reports/sweeps/geometric_fit").glob("*/[0-9]*"))
    assert [j.name for j in jobs] == ["0", "1", "2"]
    assert all((j / "report.html").is_file() and (j / "metrics.json").is_file() for j in jobs)
    # the sweep neither touched the DVC outputs nor littered the tree
    assert _reproduce(root) == []
    assert not (root / "outputs").exists() and not (root / "multirun").exists()
    # (mlflow-pending/flush.log is the git-ignored log of the detached MLflow flushers, not Hydra's)
    assert not list(root.rglob(".hydra")) and not [p for p in root.rglob("*.log") if "mlflow-pending" not in p.parts]


def test_dvc_exp_run_set_param_switches_the_optimizer(copy: dict[str, Any]) -> None:
    root = copy["root"]
    _git(root, "add", "-A")
    _git(root, "commit", "-q", "-m", "baseline")
    # the stage the parameter feeds as the target: DVC still checks (and would rerun) everything upstream of it;
    # its downstream (discover) is test_one_optimizer_parameter_reruns_only_downstream's
    res = subprocess.run(
        ["dvc", "exp", "run", "-S", "optimizer=gn", "-n", "gn-test", "geometric_fit"],
        cwd=root,
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    assert "WARNING" not in res.stdout + res.stderr and "ERROR" not in res.stdout + res.stderr, res.stderr[-2000:]
    assert "Running stage 'geometric_fit'" in res.stdout
    assert "Running stage 'simulate'" not in res.stdout and "Running stage 'prepare'" not in res.stdout
    # DVC recomposed params.yaml from conf/ + the override, byte for byte as our composition
    assert (root / "params.yaml").read_text() == params_text(root, ["optimizer=gn"])
    runs = _runs(copy["uri"], "tags.`dvc.exp_name` = 'gn-test' and tags.`robocal.stage` = 'geometric_fit'")
    assert len(runs) == 1 and runs[0].data.params["optimizer.name"] == "gn"


#: the stages a campaign without temperatures concerns, as targets: with what they depend on (plan, simulate,
#: prepare, thermal_fit, screen) they are the twin's chain up to the geometric fit and the thermal chain
NO_TEMPERATURE_TARGETS = ["geometric_fit", "validate"]


def test_a_campaign_without_temperatures_skips_the_thermal_stages(copy: dict[str, Any]) -> None:
    """The purely geometric twin has no temperature log: thermal_fit, screen and validate say so, and complete."""
    root = copy["root"]
    write_params(root, ["scenario=geometric"])
    ran = _reproduce(root, targets=NO_TEMPERATURE_TARGETS)
    assert {"simulate", "prepare", "geometric_fit", "thermal_fit", "screen", "validate"} <= set(ran), ran
    for stage in ("thermal_fit", "screen", "validate"):
        assert json.loads((root / f"reports/metrics/{stage}.json").read_text()) == {stage: "skipped"}
        m = json.loads((root / OUT[stage] / "result.json").read_text())
        assert m["status"] == "skipped" and "temperature" in m["reason"], (stage, m)
    # the tiny geometric copy calibrates 12 configurations of one reflector: 36 equations for ~30 parameters,
    # a thin campaign (fewer than 2 per parameter): it warns and says so (issue 30 item 3)
    assert json.loads((root / "reports/metrics/geometric_fit.json").read_text())["geometric_fit"] == "warning"
    assert _reproduce(root, targets=NO_TEMPERATURE_TARGETS) == []


SHARED = REPO.parent / "shared"
ABB = SHARED / "data" / "abb-irb120"


@pytest.mark.skipif(not (ABB / "poses.csv").is_file(), reason="../shared/data/abb-irb120 is not on this machine")
def test_own_data_in_one_step_as_the_readme_says(copy: dict[str, Any]) -> None:
    """The README's own-data command, verbatim, on the real ABB IRB 120 campaign: the twin is not run, the
    stages without data for them skip, the geometric fit and discovery run."""
    root = copy["root"]
    readme = (REPO / "README.md").read_text()
    # its own robot description by path (issue 30, item 8), the one the README's table figures are made with
    command = (
        "dvc exp run -S data.campaign=../shared/data/abb-irb120 -S robot_file=../shared/data/abb-irb120/robot.yaml"
    )
    assert command in readme
    shared = root.parent / "shared"  # ../shared beside the copy, as beside the repository
    if not shared.exists():
        shared.symlink_to(SHARED, target_is_directory=True)
    # `dvc exp run` needs a commit to start from: make one here, so the test does not depend on an earlier one
    _git(root, "add", "-A")
    _git(root, "commit", "-q", "--allow-empty", "-m", "before the own-data experiment")
    res = subprocess.run(command.split(), cwd=root, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    status = {s: json.loads((root / f"reports/metrics/{s}.json").read_text()) for s in STAGES}
    sim = json.loads((root / "data/raw/default/result.json").read_text())
    assert status["simulate"]["simulate"] == "skipped" and "abb-irb120" in sim["reason"]
    assert not (root / "data/raw/default/poses.csv").exists()  # the twin did not run
    for stage in ("thermal_fit", "screen", "validate", "compliance_fit"):
        assert status[stage][stage] == "skipped", (stage, status[stage])
    prep = json.loads((root / "data/interim/prepare.json").read_text())
    assert prep["robot"] == "abb-irb120" and prep["n_rows"] == (ABB / "poses.csv").read_text().count("\n") - 1
    geo = status["geometric_fit"]
    assert geo["geometric_fit"] == "ok", geo
    # calibrated beats nominal on the held-out poses (upstream's test set: 10 configurations of T4)
    assert geo["val_mean_mm"] < geo["val_nominal_mean_mm"], geo
    assert status["discover"]["discover"] == "ok"
    # the discovered model's held-out mean is the stage's headline too (a newcomer found it only in the details)
    assert 0 < status["discover"]["disc_val_mean_mm"] < geo["val_mean_mm"], status["discover"]
