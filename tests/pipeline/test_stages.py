"""dvc.yaml and the stage code agree, and the shared runner behaves (fast: no DVC run).

* each stage's ``STAGE`` declaration (params, outs, metrics, plots, cmd) matches its dvc.yaml entry;
* each stage lists as deps every robocal module it imports, directly or transitively, lazily or not
  (found statically from the import statements), so an edit to the library reruns exactly the stages using it;
* the runner: skipped results, undeclared sections, bad config naming the key, tracking failures.
"""

from __future__ import annotations

import ast
import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
SRC = REPO / "src"
STAGES_DIR = REPO / "stages"
#: the pipeline (dvc.yaml): every stage of the repository
DVC = yaml.safe_load((REPO / "dvc.yaml").read_text())["stages"]
ALL = dict(DVC)


def _load_stage(name: str) -> ModuleType:
    if str(STAGES_DIR) not in sys.path:
        sys.path.insert(0, str(STAGES_DIR))
    spec = importlib.util.spec_from_file_location(f"_stage_{name}", STAGES_DIR / f"{name}.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _entries(items: list[Any]) -> list[str]:
    return [next(iter(x)) if isinstance(x, dict) else str(x) for x in items or []]


def _module_file(name: str) -> Path | None:
    base = SRC.joinpath(*name.split("."))
    for p in (base.with_suffix(".py"), base / "__init__.py"):
        if p.is_file():
            return p
    return None


def _robocal_imports(path: Path) -> set[str]:
    """Modules ``robocal.*`` imported anywhere in ``path`` (also inside functions and TYPE_CHECKING blocks)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("robocal")}
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("robocal"):
            found.add(node.module)
            found |= {f"{node.module}.{a.name}" for a in node.names if _module_file(f"{node.module}.{a.name}")}
    return found


def _closure(start: Path) -> set[Path]:
    todo, seen = [start], set()
    while todo:
        for name in _robocal_imports(todo.pop()):
            parts = name.split(".")
            for k in range(1, len(parts) + 1):  # importing a.b.c imports a and a.b too
                f = _module_file(".".join(parts[:k]))
                if f is not None and f not in seen:
                    seen.add(f)
                    todo.append(f)
    return seen


@pytest.mark.parametrize("name", sorted(ALL))
def test_stage_declaration_matches_dvc_yaml(name: str) -> None:
    stage = _load_stage(name).STAGE
    entry = ALL[name]
    assert stage.name == name
    assert entry["cmd"] == f"python stages/{name}.py"
    # the runner puts robot_file's description in `robot` (stages/common.py): a stage reading `robot` reruns
    # when either changes
    implied = ["robot_file"] if "robot" in stage.params else []
    assert sorted(entry["params"]) == sorted([*stage.params, *implied]), "params in dvc.yaml != STAGE.params"
    assert _entries(entry["outs"]) == [stage.out]
    assert _entries(entry["metrics"]) == [stage.metrics]
    assert _entries(entry.get("plots", [])) == ([stage.plots] if stage.plots else [])
    for m in entry["metrics"] + entry.get("plots", []):
        assert next(iter(m.values())) == {"cache": False}


@pytest.mark.parametrize("name", sorted(ALL))
def test_stage_deps_cover_the_code_it_imports(name: str) -> None:
    deps = [REPO / d for d in ALL[name]["deps"] if "${" not in d]
    files = {STAGES_DIR / f"{name}.py", STAGES_DIR / "common.py"}
    files |= _closure(STAGES_DIR / f"{name}.py") | _closure(STAGES_DIR / "common.py")
    files.discard(SRC / "robocal" / "__init__.py")  # the version string only
    uncovered = sorted(str(f.relative_to(REPO)) for f in files if not any(f == d or d in f.parents for d in deps))
    assert not uncovered, f"stage {name!r} imports these files but dvc.yaml does not list them as deps"


def test_every_declared_param_section_exists() -> None:
    from robocal.pipeline import get

    params = yaml.safe_load((REPO / "params.yaml").read_text())
    for entry in ALL.values():
        for key in entry["params"]:
            get(params, key)  # a section or a dotted key: raises naming it when absent
        assert "tracking" not in entry["params"]  # where runs are recorded never reruns a stage


def test_every_dvc_stage_is_in_the_default_pipeline() -> None:
    """`dvc status`, `dvc checkout` and `dvc exp run` look at every dvc.yaml of the repository, `dvc repro` (make run)
    runs only the root one: a stage elsewhere has no dvc.lock entry after a clean run, and DVC then lists its every
    dependency as modified, fails its checkout ("Checkout failed for following targets") and warns of missing hash
    info (issue 23, item 10). So the repository holds one dvc.yaml."""
    skip = {".venv", ".git", ".dvc", "node_modules"}
    found = [
        p.relative_to(REPO).as_posix()
        for p in REPO.rglob("dvc.yaml")
        if not skip & set(p.relative_to(REPO).parts) and "sweeps" not in p.parts and "runs" not in p.parts
    ]
    assert found == ["dvc.yaml"], found


def test_the_optimizer_comparison_is_off_unless_asked_for() -> None:
    """It takes minutes: in the pipeline (so it has a lock entry) but skipping unless compare.run is true, and
    `make compare` is how to run it."""
    stage_mod = _load_stage("compare_optimizers")
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    assert params["compare"]["run"] is False
    assert "dvc exp run -S compare.run=true" in (REPO / "Makefile").read_text()
    assert "make compare" in stage_mod.OFF
    readme = (REPO / "README.md").read_text()
    assert "make compare" in readme and "experiments/dvc.yaml" not in readme


def test_dotted_params_give_the_stage_only_that_key(common: ModuleType) -> None:
    stage = common.Stage("s", ("scenario", "data.campaign"), "out", "m.json")
    cfg = {"scenario": {"a": 1}, "data": {"campaign": "x", "split": {"seed": 0}}}
    sections = common._sections(stage, cfg, "test")
    assert dict(sections) == {"scenario": {"a": 1}, "data": {"campaign": "x"}}
    from robocal.errors import ConfigError

    with pytest.raises(ConfigError, match=r"'data\.campaign'"):
        common._sections(stage, {"scenario": {}, "data": {}}, "test")


# ------------------------------------------------------------------------------------------------ runner


def _toy_repo(tmp: Path, params: dict[str, Any]) -> Path:
    (tmp / "params.yaml").write_text(yaml.safe_dump(params))
    return tmp


def _run(stage: Any, compute: Any, root: Path, argv: list[str] | None = None) -> int:
    common = sys.modules["common"]
    try:
        common.run(stage, compute, argv=argv or [], root=root)
    except SystemExit as exc:
        return int(exc.code or 0)
    return 0


@pytest.fixture()
def common() -> ModuleType:
    _load_stage("simulate")  # puts stages/ on sys.path and imports common
    return sys.modules["common"]


def test_skipped_stage_completes_with_an_explicit_result(common: ModuleType, tmp_path: Path) -> None:
    root = _toy_repo(tmp_path, {"thermal": {"a": 1}, "tracking": {"enabled": False}})
    stage = common.Stage("thermal_fit", ("thermal",), "reports/thermal", "reports/metrics/thermal_fit.json")
    code = _run(stage, lambda ctx: ctx.skip("the campaign has no temperatures.csv"), root)
    assert code == 0
    result = json.loads((root / "reports/thermal/result.json").read_text())
    assert result == {"status": "skipped", "reason": "the campaign has no temperatures.csv"}
    metrics = json.loads((root / "reports/metrics/thermal_fit.json").read_text())
    assert metrics == {"thermal_fit": "skipped"}  # one short column per stage in `dvc exp show`; why: result.json


def test_reading_an_undeclared_section_names_it(
    common: ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = _toy_repo(tmp_path, {"a": {}, "b": {}, "tracking": {"enabled": False}})
    stage = common.Stage("s", ("a",), "out", "m.json")
    assert _run(stage, lambda ctx: ctx.cfg["b"], root) == 2
    err = capsys.readouterr().err
    assert "stage s: error:" in err and "'b'" in err and "does not declare" in err


def test_missing_campaign_is_a_clear_error_naming_the_key(
    common: ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    prepare = _load_stage("prepare")
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    params["data"]["campaign"] = "data/raw/no-such-campaign"
    params["tracking"] = {"enabled": False}
    root = _toy_repo(tmp_path, params)
    assert _run(prepare.STAGE, prepare.compute, root) == 2
    err = capsys.readouterr().err
    assert "stage prepare: error:" in err
    assert "'data.campaign'" in err and "no-such-campaign" in err and "does not exist" in err
    assert not (root / "data" / "interim" / "poses.parquet").exists()


def test_geometric_fit_rejects_an_unknown_optimizer_naming_the_key() -> None:
    from robocal.errors import ConfigError

    fit = _load_stage("geometric_fit")
    cfg = {"optimizer": {"name": "pso", "max_iter": 10}, "calibration": {}}
    with pytest.raises(ConfigError, match=r"'optimizer\.name'.*'pso'"):
        fit.calibration_settings(cfg)
    # every optimizer of conf/optimizer/ is accepted (population methods too: issue 4)
    for name in ("gn", "lm", "ipopt", "igoa", "goa", "woa"):
        assert (REPO / "conf" / "optimizer" / f"{name}.yaml").is_file()
        fit.calibration_settings(
            {"optimizer": {"name": name, "max_iter": 5, "ftol": 1e-9, "xtol": 1e-9}, "calibration": {}}
        )
    settings, report = fit.calibration_settings(
        {
            "optimizer": {"name": "gn", "max_iter": 7, "ftol": 1e-9, "xtol": 1e-8, "polish": False},
            "calibration": {"noise_mm": 0.02, "report": False},
        }
    )
    # the optimizer's stopping rules are read by the one fit (robocal.calibration), not copied here
    assert settings == {"noise_mm": 0.02} and report is False


def test_mlflow_failure_keeps_the_results_and_is_printed(
    common: ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("x")
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{blocker}/mlflow.db")  # cannot be created
    root = _toy_repo(tmp_path, {"a": {"x": 1}, "tracking": {"enabled": True, "required": False}})
    stage = common.Stage("s", ("a",), "out", "reports/metrics/s.json")

    def compute(ctx: Any) -> dict[str, Any]:
        (ctx.out / "result.txt").write_text("42")
        return {"answer": 42}

    assert _run(stage, compute, root) == 0
    assert (root / "out/result.txt").read_text() == "42"
    assert json.loads((root / "reports/metrics/s.json").read_text())["answer"] == 42
    assert "robocal tracking: start run failed" in capsys.readouterr().err
    # required tracking: the files are still written, then the stage fails
    (root / "params.yaml").write_text(yaml.safe_dump({"a": {"x": 2}, "tracking": {"required": True}}))
    (root / "out/result.txt").unlink()
    assert _run(stage, compute, root) != 0
    assert (root / "out/result.txt").read_text() == "42"


def test_simulate_runs_the_twin_only_for_the_default_campaign(
    common: ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A robot without temperature sensors gets the default scenario without its thermal effect (said so); a
    campaign of one's own skips the twin."""
    from robocal.pipeline import compose

    sim = _load_stage("simulate")
    params = compose(
        REPO, ["robot=abb_irb120", "scenario.n_poses=6", "scenario.n_validation_poses=2", "plan.measured_by_twin=false"]
    )
    params["tracking"] = {"enabled": False}
    root = _toy_repo(tmp_path, params)
    assert _run(sim.STAGE, sim.compute, root) == 0
    out = root / "data" / "raw" / "default"
    assert (out / "poses.csv").is_file() and not (out / "temperatures.csv").exists()
    assert "left_out:" in (out / "scenario.yaml").read_text()
    assert "leaves out its thermal" in capsys.readouterr().out
    params["data"]["campaign"] = str(tmp_path / "my-campaign")
    (root / "params.yaml").write_text(yaml.safe_dump(params))
    assert _run(sim.STAGE, sim.compute, root) == 0
    result = json.loads((out / "result.json").read_text())
    assert result["status"] == "skipped" and "my-campaign" in result["reason"] and "twin is not run" in result["reason"]
    assert json.loads((root / sim.STAGE.metrics).read_text()) == {"simulate": "skipped"}


def test_runs_are_named_by_stage_campaign_and_experiment_and_skips_are_not_successes(
    common: ModuleType, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Issue 23, item 11: `<stage> · <campaign> · <exp name>` (own data told apart from the twin's at a glance),
    and a skipped stage ends FINISHED (issue 30 item 10: KILLED showed a red cross, as if it had failed), named
    ``(skipped)`` and tagged robocal.status=skipped, robocal.skipped=<reason>."""
    from mlflow.tracking import MlflowClient

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    monkeypatch.delenv("DVC_EXP_NAME", raising=False)
    params = {
        "thermal": {"a": 1},
        "data": {"campaign": "../shared/data/abb-irb120/"},
        "scenario": {"name": "thermal"},
        "tracking": {"required": True},  # written while the stage runs (no detached flusher to wait for)
    }
    root = _toy_repo(tmp_path, params)
    stage = common.Stage("thermal_fit", ("thermal",), "reports/thermal", "reports/metrics/thermal_fit.json")
    assert _run(stage, lambda ctx: ctx.skip("the campaign has no temperatures.csv"), root) == 0
    monkeypatch.setenv("DVC_EXP_NAME", "warm-start")
    params["data"]["campaign"] = "data/raw/default"
    (root / "params.yaml").write_text(yaml.safe_dump(params))
    assert _run(stage, lambda ctx: {"x": 1.0}, root) == 0

    client = MlflowClient(uri)
    exp = client.get_experiment_by_name("robocal")
    assert exp is not None and exp.tags.get("mlflow.experimentKind") == "custom_model_development"
    runs = {r.info.run_name: r for r in client.search_runs([exp.experiment_id])}
    assert sorted(runs) == ["thermal_fit (skipped) · abb-irb120 · workspace", "thermal_fit · twin thermal · warm-start"]
    skipped = runs["thermal_fit (skipped) · abb-irb120 · workspace"]
    assert skipped.info.status == "FINISHED"
    assert skipped.data.tags["robocal.status"] == "skipped"
    assert skipped.data.tags["robocal.skipped"] == "the campaign has no temperatures.csv"
    done = runs["thermal_fit · twin thermal · warm-start"]
    assert done.info.status == "FINISHED" and done.data.tags["robocal.status"] == "ok"
    assert "robocal.skipped" not in done.data.tags


def test_a_stage_finds_the_projects_environment_from_any_folder_below_it(common: ModuleType, tmp_path: Path) -> None:
    # `.venv/bin/dvc repro` runs dvc.yaml's `python stages/<name>.py` with the PATH's python, which may not have
    # robocal: the stage then runs again under the project's .venv (found from a `dvc exp run` workspace too)
    py = tmp_path / "repo" / ".venv" / "bin" / "python"
    py.parent.mkdir(parents=True)
    py.touch()
    assert common.project_python(tmp_path / "repo" / "stages") == py
    assert common.project_python(tmp_path / "repo" / ".dvc" / "tmp" / "exps" / "x" / "stages") == py
    assert common.project_python(tmp_path / "elsewhere") is None


def test_discover_headline_gives_the_robot_as_served_beside_the_final_figure() -> None:
    """Measurement-side effects (a tracker's scale drift) correct the held-out readings, which the service never
    sees: the stage's metrics carried only the corrected figure (newcomer pass 15: 0.0251 mm, the robot as served
    0.1686); a model without them keeps its metrics as they were."""
    mod = _load_stage("discover")
    details = {"rms_after_mm": 0.02, "n_named": 2}
    final = {"mean_position_mm": 0.0251, "as_served": {"mean_position_mm": 0.1686}}
    h = mod.headline_of({"validation": {"final": final}}, details)
    assert h["disc_val_mean_mm"] == 0.0251 and h["disc_val_served_mean_mm"] == 0.1686
    h = mod.headline_of({"validation": {"final": {"mean_position_mm": 0.03}}}, details)
    assert h == {"disc_rms_mm": 0.02, "disc_named": 2, "disc_val_mean_mm": 0.03}
