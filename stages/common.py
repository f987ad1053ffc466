"""The runner shared by every pipeline stage, and THE pattern for adding one.

A stage is a short file ``stages/<name>.py``: it declares what it reads and writes, and a ``compute(ctx)``
that calls one library function. The runner does the rest: read the parameters, open the MLflow run, time
the stage, write the metrics JSON atomically, write an explicit "skipped" result, log params / metrics /
artifacts, and turn a :class:`robocal.errors.RobocalError` into a one-line error that names the key or file.

Adding a stage (``thermal_fit`` as the example)
------------------------------------------------

1. ``stages/thermal_fit.py``::

       \"\"\"thermal_fit: temperature-dependent kinematic parameters from the interim campaign.\"\"\"

       from common import Stage, run

       STAGE = Stage(
           name="thermal_fit",
           params=("robot", "thermal"),                  # exactly the `params:` of the stage in dvc.yaml
           out="reports/thermal",                        # its `outs:` (a directory the stage fills)
           metrics="reports/metrics/thermal_fit.json",   # its `metrics:` (cache: false)
           plots="reports/plots/thermal_fit",            # its `plots:` (cache: false), or None
       )


       def compute(ctx):
           prep = ctx.read_json("data/interim/prepare.json")
           if not prep["has_temperatures"]:
               return ctx.skip("the campaign has no temperatures.csv")   # explicit skipped result, exit 0
           from robocal.workflows import thermal                      # import the library lazily

           summary = thermal.run(ctx.path("data/interim"), ctx.cfg["robot"], ctx.out, ctx.cfg["thermal"])
           ctx.artifact(ctx.out / "report.html")                       # logged to MLflow after the stage
           return {"rms_position_mm": summary["rms_position_mm"]}      # metrics (nested dicts are fine)


       if __name__ == "__main__":
           run(STAGE, compute)

2. ``dvc.yaml``::

       thermal_fit:
         cmd: python stages/thermal_fit.py
         deps:
           - stages/thermal_fit.py
           - stages/common.py
           - src/robocal/pipeline.py
           - src/robocal/tracking
           - src/robocal/workflows/__init__.py
           - src/robocal/workflows/thermal.py  # every library module or package the stage imports
           - src/robocal/thermal
           - data/interim                   # its input data
         params: [robot, thermal]           # = STAGE.params
         outs: [reports/thermal]
         metrics:
           - reports/metrics/thermal_fit.json: {cache: false}
         plots:
           - reports/plots/thermal_fit: {cache: false}

3. New parameters: a group ``conf/thermal/default.yaml`` + ``- thermal: default`` in ``conf/config.yaml``'s
   defaults, then ``make params``. ``tests/pipeline/test_stages.py`` checks that dvc.yaml and ``STAGE`` agree.

Reading a section the stage did not declare raises a ConfigError (so dvc.yaml stays honest).

Two ways a stage runs
---------------------

* ``python stages/<name>.py`` (what ``dvc repro`` / ``dvc exp run`` run): parameters from ``params.yaml``
  (DVC composed it from ``conf/``, with any ``-S`` overrides); outputs at the paths above.
* ``python stages/<name>.py key=value ...`` or ``-m key=a,b,c`` (Hydra): ``conf/`` composed with the
  overrides; each job writes into its own directory under ``reports/runs/<name>/`` or
  ``reports/sweeps/<name>/<time>/<job>/`` (the DVC-tracked outputs are not touched); a sweep is one parent
  MLflow run with one nested run per job. ``hydra/launcher=joblib`` runs the jobs in parallel.
"""

from __future__ import annotations

import json
import os
import re
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "1")


def project_python(start: Path) -> Path | None:
    """The project's ``.venv/bin/python`` in ``start`` or the nearest folder above it that has one (a ``dvc exp
    run`` workspace under ``.dvc/tmp`` finds the repository's), or None."""
    for d in (start, *start.parents):
        py = d / ".venv" / "bin" / "python"
        if py.exists():
            return py
    return None


try:  # dvc.yaml says ``python stages/<name>.py``: run as ``.venv/bin/dvc repro`` that is the PATH's python
    import robocal  # noqa: F401
except ModuleNotFoundError:
    _py = project_python(Path(__file__).resolve().parent)
    if _py is None or Path(sys.prefix) == _py.parent.parent:
        raise
    os.execv(str(_py), [str(_py), *sys.argv])  # the same stage under the project's environment

from robocal.errors import ConfigError, RobocalError  # noqa: E402
from robocal.io import reproducible, write_json, write_text  # noqa: E402
from robocal.pipeline import (  # noqa: E402
    PARAMS_FILE,
    STATUS_OK,
    STATUS_SKIPPED,
    Skipped,
    apply_robot_file,
    compose,
    get,
    load_params,
    resolve_path,
    skipped,
    write_metrics,
    write_skipped,
)

#: The repository root: the folder holding ``stages/`` (in DVC's temporary copies too).
ROOT = Path(__file__).resolve().parents[1]
#: The full metrics of a stage that returns :class:`Metrics`, in its output folder (the headline ones are in
#: ``reports/metrics/<stage>.json``).
DETAILS_FILE = "all_metrics.json"
#: Tracking settings used when the parameters have no ``tracking`` section.
TRACKING_DEFAULTS: dict[str, Any] = {"enabled": True, "experiment": "robocal", "uri": None, "required": False}


#: The explicit result a skipped stage writes into its output folder (robocal.pipeline.write_skipped).
SKIPPED_FILE = "result.json"
#: The campaign the twin writes (conf/config.yaml's default data.campaign).
DEFAULT_CAMPAIGN = "data/raw/default"


@dataclass(frozen=True)
class Stage:
    """What a stage reads and writes; must agree with its entry in ``dvc.yaml``."""

    name: str
    params: tuple[str, ...]
    out: str
    metrics: str
    plots: str | None = None
    #: True: the MLflow run is written while the stage runs (it nests runs under it); False: recorded and
    #: written by a detached flusher (robocal.tracking.PendingRun), which saves the stage MLflow's start-up.
    inline_tracking: bool = False


class Sections(dict):  # type: ignore[type-arg]
    """The parameter sections a stage declared; reading another one is an error that names it."""

    stage: str = ""

    def __missing__(self, key: str) -> Any:
        raise ConfigError(
            f"stage {self.stage!r} reads the parameter section '{key}' but does not declare it: add it to "
            f"STAGE.params and to the stage's params in dvc.yaml. Declared: {sorted(self)}"
        )


@dataclass
class Context:
    """What ``compute(ctx)`` gets.

    cfg : the declared parameter sections (plain dicts); out : the output directory (created);
    metrics_path / plots : where the runner writes metrics and where plots go (created); root : the
    repository root; hydra : True when run by Hydra (outputs then live in the job directory); tracker : the
    :class:`robocal.tracking.StageRun` (log extra things with it).
    """

    stage: Stage
    root: Path
    cfg: Sections
    out: Path
    metrics_path: Path
    plots: Path | None
    hydra: bool
    tracker: Any
    artifacts: list[Path] = field(default_factory=list)

    def path(self, value: str | Path) -> Path:
        """A path from the config or a stage input: absolute as given, else relative to the repository root."""
        return resolve_path(self.root, value)

    def get(self, key: str, default: Any = ..., types: type | tuple[type, ...] | None = None) -> Any:
        """One dotted key of the declared sections, e.g. ``ctx.get("data.campaign")``; errors name the key."""
        section = key.split(".", 1)[0]
        self.cfg[section]  # raises for an undeclared section
        return get(self.cfg, key, types=types) if default is ... else get(self.cfg, key, default, types)

    def read_json(self, value: str | Path) -> Any:
        p = self.path(value)
        if not p.is_file():
            raise ConfigError(f"stage {self.stage.name!r}: missing input {p} (run the upstream stage first)")
        return json.loads(p.read_text(encoding="utf-8"))

    def artifact(self, path: str | Path) -> None:
        """Log ``path`` (file or directory) to MLflow once the stage has written its outputs."""
        self.artifacts.append(Path(path))

    def own_campaign(self) -> str | None:
        """``data.campaign`` when it names a campaign of the user's own, None when it is the twin's default
        (:data:`DEFAULT_CAMPAIGN`); the stage must declare ``data.campaign`` among its params."""
        campaign = self.get("data.campaign", types=str)
        return None if self.path(campaign).resolve() == self.path(DEFAULT_CAMPAIGN).resolve() else campaign

    def upstream_skipped(self, out: str | Path) -> str | None:
        """The reason an upstream stage whose output folder is ``out`` skipped (its ``result.json``), or None
        when it ran: a stage that needs its results skips too, saying why."""
        p = self.path(out) / SKIPPED_FILE
        if not p.is_file():
            return None
        result = json.loads(p.read_text(encoding="utf-8"))
        return str(result.get("reason", "")) if result.get("status") == STATUS_SKIPPED else None

    @staticmethod
    def skip(reason: str) -> Skipped:
        """Return this from ``compute``: explicit ``{"status": "skipped", "reason": ...}`` result, exit 0."""
        return skipped(reason)


@dataclass(frozen=True)
class Metrics:
    """What ``compute`` may return instead of a plain mapping: a few ``headline`` numbers for the metrics
    file (``dvc metrics show`` / ``dvc exp show``: keep it short, names unique across stages) and
    ``details`` that go to MLflow only (the stage's own JSON outputs hold them too). ``status`` is "ok"
    unless the stage found the result unusable (e.g. "failed": worse than its start) or usable with care
    ("warning": e.g. a fit that stopped on its iteration limit)."""

    headline: Mapping[str, Any]
    details: Mapping[str, Any] = field(default_factory=dict)
    status: str = STATUS_OK


Compute = Callable[[Context], "Mapping[str, Any] | Metrics | Skipped | None"]


def _sections(stage: Stage, cfg: Mapping[str, Any], source: str) -> Sections:
    """The declared parameters: whole sections (``robot``) or single keys of a section (``data.campaign``,
    which gives the stage ``{"data": {"campaign": ...}}`` and nothing else of ``data``)."""
    missing = [s for s in stage.params if s.split(".", 1)[0] not in cfg]
    if missing:
        raise ConfigError(f"{source}: missing parameter section(s) {missing} needed by stage {stage.name!r}")
    out = Sections()
    for key in stage.params:
        section, _, rest = key.partition(".")
        if not rest:
            out[section] = cfg[section]
            continue
        node = out.setdefault(section, {})
        parts = rest.split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = get(cfg, key)
    out.stage = stage.name
    return out


def run_title(stage: str, cfg: Mapping[str, Any], experiment: str | None = None) -> str:
    """The MLflow run name ``<stage> · <campaign> · <experiment>`` (robocal.tracking.run_title): the campaign
    from ``data.campaign`` (``twin <scenario>`` for the twin's), read here for the name only (it reruns nothing);
    the experiment is DVC's, else ``experiment`` (a Hydra job's), else ``workspace``."""
    from robocal.tracking.naming import campaign_label
    from robocal.tracking.naming import run_title as title

    data = cfg.get("data") if isinstance(cfg.get("data"), Mapping) else {}
    scenario = cfg.get("scenario") if isinstance(cfg.get("scenario"), Mapping) else {}
    campaign = data.get("campaign") if isinstance(data, Mapping) else None
    name = scenario.get("name") if isinstance(scenario, Mapping) else None
    label = campaign_label(None if campaign is None else str(campaign), None if name is None else str(name))
    return title(stage, label, experiment)


def _tracking(cfg: Mapping[str, Any]) -> dict[str, Any]:
    t = cfg.get("tracking") or {}
    if not isinstance(t, Mapping):
        raise ConfigError(f"The config key 'tracking' must be a mapping. Got {t!r} instead.")
    unknown = sorted(set(t) - set(TRACKING_DEFAULTS))
    if unknown:
        raise ConfigError(f"unknown tracking setting(s) {unknown}; known: {sorted(TRACKING_DEFAULTS)}")
    return {**TRACKING_DEFAULTS, **t}


def execute(
    stage: Stage,
    compute: Compute,
    cfg: Mapping[str, Any],
    *,
    root: Path,
    out: Path,
    metrics_path: Path,
    plots: Path | None,
    hydra: bool = False,
    tags: Mapping[str, str] | None = None,
    run_name: str | None = None,
) -> dict[str, Any]:
    """Run one stage job: tracking run, ``compute``, metrics / skipped result, artifacts.

    Writes ``metrics_path`` = ``{<stage name>: status, **headline}`` (status "ok", "warning", "skipped" or "failed").
    Returns everything: ``status`` (and ``reason`` of a skip), details, headline numbers and the times."""
    from robocal.tracking.pending import PendingRun
    from robocal.tracking.runs import StageRun

    cfg = apply_robot_file(cfg, root)  # robot_file=<path>: that description is the `robot` every stage reads
    sections = _sections(stage, cfg, "the config" if hydra else PARAMS_FILE)
    tcfg = _tracking(cfg)
    run_name = run_title(stage.name, cfg, run_name)
    common = {"enabled": bool(tcfg["enabled"]), "uri": tcfg["uri"], "experiment": str(tcfg["experiment"])}
    tracker: Any
    if hydra or stage.inline_tracking or tcfg["required"]:  # nested runs, or the run must exist before exit
        tracker = StageRun(stage.name, **common, required=bool(tcfg["required"]), tags=tags, run_name=run_name)
    else:  # recorded now, written to MLflow by a detached flusher: no MLflow import in the stage
        tracker = PendingRun(stage.name, **common, tags=tags, run_name=run_name)
    out.mkdir(parents=True, exist_ok=True)
    if plots is not None:
        plots.mkdir(parents=True, exist_ok=True)
    ctx = Context(stage, root, sections, out, metrics_path, plots, hydra, tracker)
    (out / SKIPPED_FILE).unlink(missing_ok=True)  # an earlier skip of this folder must not outlive a run
    t0 = time.perf_counter()
    # DVC-tracked outputs (params.yaml mode): same config, same bytes -- no timings in any JSON written,
    # floats rounded (robocal.io.reproducible). Timings go to MLflow and the console.
    with tracker, reproducible(not hydra):  # FAILED in MLflow when compute raises; the error then propagates
        tracker.log_params(dict(sections))
        tracker.log_text(_yaml(dict(sections)), "params.yaml")
        tc = time.perf_counter()
        result = compute(ctx)
        times = {"compute_time_s": time.perf_counter() - tc, "wall_time_s": time.perf_counter() - t0}
        details: dict[str, Any] = {}
        if isinstance(result, Skipped):
            outcome = {**write_skipped(out, result.reason), "skipped": 1}
            headline: dict[str, Any] = {}
            print(f"stage {stage.name}: skipped: {result.reason}")
            tracker.mark_skipped(result.reason)  # not a green FINISHED run in MLflow
            if plots is not None:  # an empty plots folder makes DVC warn; say why there is no plot
                write_text(plots / "skipped.svg", _skipped_svg(result.reason))
        elif isinstance(result, Metrics):
            outcome, headline, details = {"status": result.status}, dict(result.headline), dict(result.details)
            if details:  # the full set, beside the stage's other outputs
                write_json(out / DETAILS_FILE, {**outcome, **details})
        else:
            outcome, headline = {"status": STATUS_OK}, dict(result or {})
        status = outcome["status"]
        # the metrics file: the status under the stage's name (one short, unique column per stage in
        # `dvc exp show`; the reason of a skip is in <out>/result.json), then the headline numbers
        write_metrics(metrics_path, {stage.name: status, **headline})
        tracker.set_tags({"robocal.status": status})
        everything = {**outcome, **details, **headline}
        tracker.log_metrics({**everything, **times})
        for path in [metrics_path, *([plots] if plots is not None and any(plots.iterdir()) else []), *ctx.artifacts]:
            tracker.log_artifact(path, _artifact_dir(path, out, plots))
    wall = time.perf_counter() - t0
    print(f"stage {stage.name}: {status} in {wall:.2f} s; metrics {_rel(metrics_path, root)}")
    return {**everything, **times}


def _skipped_svg(reason: str) -> str:
    from html import escape

    return (
        '<svg xmlns="http://www.w3.org/2000/svg" width="640" height="60" viewBox="0 0 640 60">'
        '<text x="10" y="35" font-family="sans-serif" font-size="14">'
        f"stage skipped: {escape(reason)}</text></svg>\n"
    )


def _artifact_dir(path: Path, out: Path, plots: Path | None) -> str | None:
    if plots is not None and path == plots:
        return "plots"
    try:
        rel = path.resolve().relative_to(out.resolve())
    except ValueError:
        return None
    parent = rel.parent.as_posix()
    return None if parent in ("", ".") else parent


def _yaml(obj: Any) -> str:
    import yaml

    return yaml.safe_dump(obj, sort_keys=False)


def _rel(path: Path, root: Path) -> str:
    try:
        return str(path.resolve().relative_to(root.resolve()))
    except ValueError:
        return str(path)


#: The prepare stage's copy of the user's campaign, and the file saying where it came from.
INTERIM = "data/interim"
PREPARE_INFO = "data/interim/prepare.json"


def user_message(exc: BaseException, root: Path) -> str:
    """The error's text with the prepare stage's interim copy (``data/interim/poses.parquet`` ...) replaced by the
    user's own campaign file: rows and columns are the same (the copy keeps every row in file order), and the
    user knows their file, not ours."""
    text = str(exc)
    info = root / PREPARE_INFO
    if (INTERIM not in text and str((root / INTERIM).resolve()) not in text) or not info.is_file():
        return text
    try:
        source = json.loads(info.read_text(encoding="utf-8")).get("source")
    except (OSError, ValueError):
        return text
    if not source:
        return text
    folder = resolve_path(root, source)
    for kind in ("poses", "temperatures"):
        found = [folder / f"{kind}{ext}" for ext in (".csv", ".parquet") if (folder / f"{kind}{ext}").is_file()]
        mine = str(Path(source) / found[0].name) if found else str(Path(source) / f"{kind}.*")
        for form in (str((root / INTERIM / f"{kind}.parquet").resolve()), f"{INTERIM}/{kind}.parquet"):
            text = text.replace(form, mine)
    for form in (str((root / INTERIM).resolve()), INTERIM):  # the folder itself, not a file in it
        text = re.sub(re.escape(form) + r"(?![\w/.])", lambda _m: str(source), text)
    return text


def run(stage: Stage, compute: Compute, argv: Sequence[str] | None = None, root: Path | None = None) -> None:
    """Entry point of ``stages/<name>.py``: params.yaml mode without arguments, Hydra mode with them."""
    args = list(sys.argv[1:] if argv is None else argv)
    root = (root or ROOT).resolve()
    os.chdir(root)  # config paths are relative to the repository root, wherever the stage is started from
    if args:
        sys.exit(_run_hydra(stage, compute, root, args))
    try:
        cfg = load_params(root / PARAMS_FILE)
        execute(
            stage,
            compute,
            cfg,
            root=root,
            out=root / stage.out,
            metrics_path=root / stage.metrics,
            plots=None if stage.plots is None else root / stage.plots,
        )
    except RobocalError as exc:
        print(f"stage {stage.name}: error: {user_message(exc, root)}", file=sys.stderr)
        sys.exit(2)


def _run_hydra(stage: Stage, compute: Compute, root: Path, args: list[str]) -> int:
    import hydra
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import OmegaConf

    from robocal import tracking

    multirun = any(a in ("-m", "--multirun") for a in args)
    if not multirun:  # a bad override (robot=../cell7/robot.yaml) as one line, not Hydra's report
        try:
            apply_robot_file(compose(root, [a for a in args if not a.startswith("-")]), root)
        except ConfigError as exc:
            print(f"stage {stage.name}: error: {exc}", file=sys.stderr)
            return 2
    parent = None
    if multirun:
        # tracking settings of the sweep: conf/ with the (non-swept) tracking overrides only
        tov = [a for a in args if a.lstrip("+~").startswith("tracking") and "," not in a]
        tcfg = _tracking(compose(root, tov))
        parent = tracking.start_sweep(
            stage.name,
            [a for a in args if not a.startswith("-")],
            enabled=bool(tcfg["enabled"]),
            uri=tcfg["uri"],
            experiment=str(tcfg["experiment"]),
        )

    def job(cfg: Any) -> dict[str, Any]:
        data = OmegaConf.to_container(cfg, resolve=True)
        assert isinstance(data, dict)
        hc = HydraConfig.get()
        job_dir = Path(hc.runtime.output_dir).resolve()
        overrides = " ".join(hc.overrides.task)
        tags = {"hydra.overrides": overrides or "(none)", "hydra.job_dir": str(job_dir)}
        run_name = f"hydra {overrides}".strip()
        if multirun:
            tags["hydra.job_num"] = str(hc.job.num)
            run_name = f"sweep #{hc.job.num} {overrides}".strip()
        try:
            return execute(
                stage,
                compute,
                {str(k): v for k, v in data.items()},
                root=root,
                out=job_dir,
                metrics_path=job_dir / "metrics.json",
                plots=None if stage.plots is None else job_dir / "plots",
                hydra=True,
                tags=tags,
                run_name=run_name,
            )
        except RobocalError as exc:
            print(f"stage {stage.name}: error: {user_message(exc, root)}", file=sys.stderr)
            raise

    app = hydra.main(version_base=None, config_path=str(root / "conf"), config_name="config")(job)
    saved = sys.argv
    sys.argv = [saved[0], *args, f"hydra.job.name={stage.name}"]
    code = 0
    try:
        app()
    except SystemExit as exc:  # Hydra exits 1 after printing a job's error
        code = int(exc.code or 0) if not isinstance(exc.code, str) else 1
    finally:
        sys.argv = saved
        if parent is not None:
            tracking.end_sweep(parent, "FINISHED" if code == 0 else "FAILED")
    return code
