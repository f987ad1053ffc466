"""Where a robot description is found (:mod:`robocal.robot`'s lookup order): a path as given, else
``<name>.yaml`` in the current project's ``conf/robot/`` and then the robots shipped with the package. Split from
:mod:`robocal.robot` by role (the names are re-exported there)."""

from __future__ import annotations

from pathlib import Path

from robocal.errors import ConfigError

#: The robot descriptions shipped with the package (``conf/robot/*.yaml`` are links to them, for Hydra).
SHIPPED_ROBOT_DIR = Path(__file__).resolve().parent / "robots"


def project_robot_dir(start: str | Path | None = None) -> Path | None:
    """``conf/robot/`` of the current project: the nearest of ``start`` (default: the working directory) and its
    parents that has one; None when none has."""
    here = Path(start) if start is not None else Path.cwd()
    for d in (here, *here.parents):
        if (d / "conf" / "robot").is_dir():
            return d / "conf" / "robot"
    return None


def robot_dirs(conf_dir: str | Path | None = None) -> list[Path]:
    """The folders a robot name is looked up in, in order: ``conf_dir`` alone when given, else the current
    project's ``conf/robot/`` (:func:`project_robot_dir`) and then the packaged robots."""
    if conf_dir is not None:
        return [Path(conf_dir)]
    project = project_robot_dir()
    dirs = [] if project is None else [project]
    if project is None or project.resolve() != SHIPPED_ROBOT_DIR.resolve():
        dirs.append(SHIPPED_ROBOT_DIR)
    return dirs


def is_robot_path(name_or_path: str | Path) -> bool:
    """Whether a robot reference is a path (a ``.yaml`` / ``.yml`` / URDF name or an existing file), not a name."""
    s = str(name_or_path)
    return s.endswith((".yaml", ".yml", ".urdf")) or ".urdf#" in s or Path(s).is_file()


def find_robot(name_or_path: str | Path, conf_dir: str | Path | None = None) -> Path:
    """The YAML file of a robot reference, by the one lookup order: a path as given, else ``<name>.yaml`` in
    :func:`robot_dirs` (the current project's ``conf/robot/``, then the packaged robots).

    Raises :class:`ConfigError` naming the folders searched and the robots they have."""
    if is_robot_path(name_or_path):
        path = Path(name_or_path)
        if not path.is_file():
            raise ConfigError(f"robot description {path} does not exist")
        return path
    name = str(name_or_path)
    dirs = robot_dirs(conf_dir)
    if name and "/" not in name and "\\" not in name:
        for d in dirs:
            if (d / f"{name}.yaml").is_file():
                return d / f"{name}.yaml"
    known = sorted({x.stem for d in dirs if d.is_dir() for x in d.glob("*.yaml")})
    where = " nor ".join(str(d) for d in dirs)
    raise ConfigError(f"unknown robot {name!r}: no {name}.yaml in {where}; known robots: {known} (or give a YAML path)")


__all__ = ["SHIPPED_ROBOT_DIR", "find_robot", "is_robot_path", "project_robot_dir", "robot_dirs"]
