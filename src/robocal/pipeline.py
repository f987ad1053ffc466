"""Helpers shared by the pipeline stages (``stages/*.py``): parameters in, results out.

* Parameters. ``conf/`` (Hydra) owns them; ``params.yaml`` is generated from it by DVC's Hydra composition.
  :func:`compose` composes ``conf/`` exactly as DVC does (resolved, the ``hydra`` node left out),
  :func:`params_text` is the text DVC writes, :func:`write_params` regenerates ``params.yaml`` with DVC's own
  function, :func:`load_params` reads the sections a stage uses from ``params.yaml``, and :func:`get` fetches
  one dotted key with an error that names it.
* Results. :func:`write_metrics` writes a stage's metrics JSON (atomically), :func:`write_skipped` writes the
  explicit ``{"status": "skipped", "reason": ...}`` result of a stage that has nothing to do on a campaign.

Command line (``make params`` uses it)::

    python -m robocal.pipeline params [--root DIR] [override ...]   # regenerate params.yaml from conf/
    python -m robocal.pipeline check  [--root DIR]                  # exit 1 if params.yaml is out of sync
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from robocal.errors import ConfigError
from robocal.io import write_json
from robocal.status import StageStatus

#: Name of the generated parameter file (DVC's default params file).
PARAMS_FILE = "params.yaml"
#: Hydra config directory and primary config name (DVC's defaults for ``hydra.enabled``).
CONF_DIR = "conf"
CONFIG_NAME = "config"
#: Status values of a stage result (:class:`robocal.status.StageStatus`).
STATUS_OK = StageStatus.OK
STATUS_SKIPPED = StageStatus.SKIPPED

_MISSING = object()


# ----------------------------------------------------------------------------------------------- parameters


def compose(root: str | Path, overrides: Sequence[str] = ()) -> dict[str, Any]:
    """Compose ``<root>/conf/config.yaml`` with Hydra overrides, resolved, as plain Python (what DVC writes)."""
    from omegaconf import OmegaConf

    cfg = _compose_omegaconf(root, overrides)
    out = OmegaConf.to_container(cfg, resolve=True)
    assert isinstance(out, dict)
    return {str(k): v for k, v in out.items()}


def _compose_omegaconf(root: str | Path, overrides: Sequence[str]) -> Any:
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.errors import HydraException
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    conf = (Path(root) / CONF_DIR).resolve()
    if not (conf / f"{CONFIG_NAME}.yaml").is_file():
        raise ConfigError(f"no Hydra config {conf / (CONFIG_NAME + '.yaml')}")
    if GlobalHydra.instance().is_initialized():  # e.g. inside a Hydra app
        GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(str(conf), version_base=None):
            cfg = hydra_compose(config_name=CONFIG_NAME, overrides=list(overrides))
        OmegaConf.resolve(cfg)
    except (HydraException, OmegaConfBaseException) as exc:
        raise ConfigError(override_error(conf, overrides, exc)) from None
    return cfg


def override_error(conf: Path, overrides: Sequence[str], exc: BaseException) -> str:
    """Hydra's composition error as one line that names the override: an unknown option of a config group
    (``robot=../cell7/robot.yaml``) lists the group's options and, for ``robot``, says how to give a file by path."""
    for ov in overrides:
        key, sep, value = ov.lstrip("+~").partition("=")
        group = conf / key
        if not sep or not group.is_dir() or (group / f"{value}.yaml").is_file():
            continue
        options = sorted(p.stem for p in group.glob("*.yaml"))
        hint = f"; a robot description by path is {ROBOT_FILE}={value}" if key == "robot" else ""
        return f"{ov}: {key!r} has no option {value!r} (conf/{key}/: {', '.join(options)}){hint}"
    first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return f"the configuration (conf/ with overrides {list(overrides)}) does not compose: {first}"


#: The top-level key naming a robot description file; when set it replaces the ``robot`` group's content.
ROBOT_FILE = "robot_file"


def apply_robot_file(cfg: Mapping[str, Any], root: str | Path) -> dict[str, Any]:
    """``cfg`` with ``robot`` replaced by the description in the file ``robot_file`` names (a path relative to the
    repository root, or absolute), when it names one; the twin's ``scenario.robot``, composed from the robot's
    name, follows it. The description is checked (:func:`robocal.robot.robot_from_dict`): errors name the file."""
    out = dict(cfg)
    value = out.get(ROBOT_FILE)
    if value is None or value == "":
        return out
    if not isinstance(value, str | Path):
        raise ConfigError(
            f"The config key '{ROBOT_FILE}' must be a path to a robot YAML or URDF. Got {value!r} instead."
        )
    from robocal.robot import robot_from_dict

    text = str(value)
    urdf = text.endswith(".urdf") or ".urdf#" in text  # a URDF, optionally path.urdf#BASE:TIP (as --robot takes)
    path = resolve_path(root, text.split("#", 1)[0] if urdf else value)
    if not path.is_file():
        raise ConfigError(
            f"The config key '{ROBOT_FILE}' points at {str(value)!r}, which is not a file ({path}; a relative path "
            "is relative to the repository root)"
        )
    if urdf:  # the URDF as the robot YAML it describes (POE), by robocal.robot's reader (imported only then)
        import importlib

        from robocal.robot import URDF_DICT_READER

        mod, func = URDF_DICT_READER.split(":")
        frag = text.split("#", 1)[1] if "#" in text else None
        data: Any = getattr(importlib.import_module(mod), func)(str(path) + (f"#{frag}" if frag is not None else ""))
    else:
        try:
            data = yaml.safe_load(path.read_text(encoding="utf-8"))
        except yaml.YAMLError as exc:
            first = str(exc).splitlines()[0] if str(exc) else "invalid"
            raise ConfigError(f"{ROBOT_FILE} {value}: not valid YAML: {first}") from None
    if isinstance(data, dict) and "joints" not in data and isinstance(data.get("robot"), dict):
        data = data["robot"]  # a Hydra group file may nest the description under 'robot:'
    if isinstance(data, dict):
        data = {"name": path.stem, **data}
    robot = robot_from_dict(data, source=f"{ROBOT_FILE} {value}")  # raises naming the file and the key
    group = out.get("robot")
    before = group.get("name") if isinstance(group, Mapping) else None
    out["robot"] = data
    scenario = out.get("scenario")
    if isinstance(scenario, Mapping) and scenario.get("robot") == before:  # composed from ${robot.name}
        out["scenario"] = {**scenario, "robot": robot.name}
    return out


def params_text(root: str | Path, overrides: Sequence[str] = ()) -> str:
    """The exact text DVC's Hydra composition writes to ``params.yaml`` (``OmegaConf.to_yaml`` of the
    resolved composition; see ``dvc/utils/hydra.py: compose_and_dump``)."""
    from omegaconf import OmegaConf

    return str(OmegaConf.to_yaml(_compose_omegaconf(root, overrides)))


def write_params(root: str | Path, overrides: Sequence[str] = ()) -> Path:
    """Regenerate ``<root>/params.yaml`` from ``conf/`` with DVC's own composition function (byte-identical to
    what ``dvc exp run`` writes)."""
    from dvc.utils.hydra import compose_and_dump

    root = Path(root).resolve()
    out = root / PARAMS_FILE
    compose_and_dump(out, str(root / CONF_DIR), None, CONFIG_NAME, str(root), list(overrides))
    return out


def load_params(path: str | Path, sections: Iterable[str] | None = None) -> dict[str, Any]:
    """Read ``params.yaml`` and return the named top-level sections (all when ``sections`` is None).

    Raises :class:`ConfigError` naming the file and the missing section.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"no parameter file {path}: run `make params` (or `dvc exp run`) to generate it from conf/")
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: must be a mapping of sections. Got {type(data).__name__} instead.")
    if sections is None:
        return data
    missing = [s for s in sections if s not in data]
    if missing:
        raise ConfigError(f"{path}: missing section(s) {missing}; present: {sorted(data)}")
    return {s: data[s] for s in sections}


def get(cfg: Mapping[str, Any], key: str, default: Any = _MISSING, types: type | tuple[type, ...] | None = None) -> Any:
    """``cfg["a"]["b"]`` for ``key="a.b"``; a missing key (without default) or a wrong type is a
    :class:`ConfigError` that names the key."""
    node: Any = cfg
    for i, part in enumerate(key.split(".")):
        if not isinstance(node, Mapping) or part not in node:
            if default is not _MISSING:
                return default
            where = ".".join(key.split(".")[:i]) or "the config"
            raise ConfigError(f"The config key '{key}' is missing (no '{part}' in {where}).")
        node = node[part]
    if types is not None and not isinstance(node, types):
        names = types.__name__ if isinstance(types, type) else " or ".join(t.__name__ for t in types)
        raise ConfigError(f"The config key '{key}' must be of type {names}. Got {node!r} instead.")
    return node


def resolve_path(root: str | Path, value: str | Path) -> Path:
    """A config path: absolute as given, relative ones against the repository root."""
    p = Path(value).expanduser()
    return p if p.is_absolute() else Path(root) / p


def campaign_dir(root: str | Path, cfg: Mapping[str, Any], key: str = "data.campaign") -> Path:
    """The campaign folder named by ``key``, checked: it exists and holds ``poses.csv`` or ``poses.parquet``."""
    value = get(cfg, key, types=(str, Path))
    path = resolve_path(root, value)
    if not path.exists():
        raise ConfigError(f"The config key '{key}' points at {str(value)!r}, which does not exist ({path}).")
    if not path.is_dir():
        raise ConfigError(f"The config key '{key}' must name a campaign folder. Got {str(value)!r}, a file.")
    if not any((path / f"poses{ext}").is_file() for ext in (".csv", ".parquet")):
        raise ConfigError(
            f"The config key '{key}' points at {str(value)!r}, which has no poses.csv or poses.parquet "
            "(see the data contract in the README)."
        )
    return path


# ----------------------------------------------------------------------------------------------- results


@dataclass(frozen=True)
class Skipped:
    """What a stage returns when it has nothing to do on this campaign (no temperatures, no payload, ...)."""

    reason: str


def skipped(reason: str) -> Skipped:
    """Return this from a stage's ``compute``: the runner writes the explicit skipped result and metrics."""
    return Skipped(str(reason))


def write_metrics(path: str | Path, metrics: Mapping[str, Any]) -> Path:
    """Write a stage's metrics JSON atomically (numpy values converted, NaN/inf as null)."""
    return write_json(path, dict(metrics))


def write_skipped(out_dir: str | Path, reason: str, metrics_path: str | Path | None = None) -> dict[str, Any]:
    """Write ``<out_dir>/result.json`` = ``{"status": "skipped", "reason": ...}`` (and the same, with
    ``skipped: 1``, as metrics when ``metrics_path`` is given) so the stage completes and says why."""
    result = {"status": STATUS_SKIPPED, "reason": str(reason)}
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "result.json", result)
    if metrics_path is not None:
        write_metrics(metrics_path, {**result, "skipped": 1})
    return result


# ----------------------------------------------------------------------------------------------- command line


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m robocal.pipeline", description="params.yaml from conf/")
    parser.add_argument("action", choices=["params", "check"], help="params: regenerate; check: compare")
    parser.add_argument("--root", default=".", help="repository root (default: the current directory)")
    parser.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. optimizer=gn")
    args = parser.parse_args(argv)
    root = Path(args.root)
    try:
        if args.action == "params":
            params_text(root, args.overrides)  # a composition error as one line before DVC's writer runs
            print(f"wrote {write_params(root, args.overrides)}")
            return 0
        expected = params_text(root, args.overrides)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    current = (root / PARAMS_FILE).read_text(encoding="utf-8") if (root / PARAMS_FILE).is_file() else ""
    if current != expected:
        print(f"{root / PARAMS_FILE} is out of sync with conf/: run `make params`", file=sys.stderr)
        return 1
    print(f"{root / PARAMS_FILE} is in sync with conf/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
