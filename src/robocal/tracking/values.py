"""What a run logs: nested parameters flattened, keys in MLflow's charset, numeric metrics, the default tags."""

from __future__ import annotations

import math
import os
import re
import subprocess
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from robocal.tracking.store import repo_root

# ----------------------------------------------------------------------------------------------- values


def flatten(mapping: Mapping[str, Any], prefix: str = "", sep: str = ".") -> dict[str, Any]:
    """Nested mappings to ``{"a.b.c": value}``; lists of scalars become their string form, lists holding
    mappings are left out (too wide for a parameter table: log the whole config as an artifact instead)."""
    out: dict[str, Any] = {}
    for key, value in mapping.items():
        name = f"{prefix}{sep}{key}" if prefix else str(key)
        if isinstance(value, Mapping):
            out.update(flatten(value, name, sep))
        elif isinstance(value, list | tuple):
            if not any(isinstance(v, Mapping | list | tuple) for v in value):
                out[name] = str(list(value))
        else:
            out[name] = value
    return out


_KEY_OK = re.compile(r"[^A-Za-z0-9_\-. :/]")


def param_key(key: str) -> str:
    """``key`` in MLflow's name charset (alphanumerics, ``_ - . space : /``): others become ``_``, ``^`` as in
    ``T_j6_C^2`` becomes ``_pow`` (so the logged key still reads as the power it is)."""
    return _KEY_OK.sub("_", key.replace("^", "_pow"))


def numeric_metrics(mapping: Mapping[str, Any]) -> dict[str, float]:
    """The numeric leaves of a (nested) mapping, flattened; bools count as 0/1, non-finite values are dropped."""
    out: dict[str, float] = {}
    for key, value in flatten(mapping).items():
        if isinstance(value, bool):
            out[key] = float(value)
        elif isinstance(value, int | float) and math.isfinite(float(value)):
            out[key] = float(value)
        elif hasattr(value, "item") and isinstance(value.item(), int | float):  # numpy scalars
            f = float(value.item())
            if math.isfinite(f):
                out[key] = f
    return out


def git_commit(cwd: Path | None = None) -> str | None:
    """The current git commit of the repository, or None (no git, no commit yet)."""
    try:
        res = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=cwd or repo_root(),
            capture_output=True,
            text=True,
            timeout=5,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    sha = res.stdout.strip()
    return sha if res.returncode == 0 and len(sha) == 40 else None


def default_tags(stage: str) -> dict[str, str]:
    """Tags every run gets: stage name, DVC experiment / stage when DVC runs it, git commit when there is one."""
    tags = {"robocal.stage": stage}
    for env, tag in (("DVC_EXP_NAME", "dvc.exp_name"), ("DVC_STAGE", "dvc.stage"), ("DVC_ROOT", "dvc.root")):
        if os.environ.get(env):
            tags[tag] = os.environ[env]
    sha = git_commit()
    if sha:
        tags["mlflow.source.git.commit"] = sha
    return tags
