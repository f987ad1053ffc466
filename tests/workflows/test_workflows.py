"""Every workflow is ``robocal.workflows.<name>.run`` with one signature; ``robocal.workflows.run`` dispatches."""

from __future__ import annotations

import importlib
import inspect
import json
from typing import Any

import pytest

from robocal import workflows
from robocal.errors import ConfigError

P = inspect.Parameter
#: the shared head of every workflow's run: (name, kind, default, annotation)
COMMON = [
    ("data_dir", P.POSITIONAL_OR_KEYWORD, P.empty, "str | Path | None"),
    ("robot", P.POSITIONAL_OR_KEYWORD, P.empty, "str | Path | RobotDescription"),
    ("out_dir", P.POSITIONAL_OR_KEYWORD, P.empty, "str | Path"),
    ("settings", P.POSITIONAL_OR_KEYWORD, None, "Mapping[str, Any] | None"),
    ("split", P.KEYWORD_ONLY, None, "Mapping[str, Any] | None"),
    ("campaign", P.KEYWORD_ONLY, None, "Campaign | None"),
    ("report", P.KEYWORD_ONLY, True, "bool"),
]
#: each workflow's keyword-only extras (all default None)
EXTRAS = {
    "geometric": ["optimizer"],
    "thermal": ["screen"],
    "compliance": ["truth"],
    "discovery": ["sessions", "session_tool"],
}


def test_the_registry_names_every_workflow_module() -> None:
    assert set(workflows.NAMES) == set(EXTRAS)


@pytest.mark.parametrize("name", sorted(EXTRAS))
def test_every_workflow_shares_the_signature(name: str) -> None:
    sig = inspect.signature(importlib.import_module(f"robocal.workflows.{name}").run)
    params = list(sig.parameters.values())
    head = [(p.name, p.kind, p.default, p.annotation) for p in params[: len(COMMON)]]
    assert head == COMMON
    extras = params[len(COMMON) :]
    assert [p.name for p in extras] == EXTRAS[name]
    assert all(p.kind is P.KEYWORD_ONLY and p.default is None for p in extras)
    assert sig.return_annotation == "dict[str, Any]"


@pytest.mark.parametrize("name", sorted(EXTRAS))
def test_run_dispatches_by_name(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    module = importlib.import_module(f"robocal.workflows.{name}")
    seen: list[tuple[Any, ...]] = []

    def fake(*args: Any, **kw: Any) -> dict[str, Any]:
        seen.append((args, kw))
        return {"workflow": name}

    monkeypatch.setattr(module, "run", fake)
    assert workflows.run(name, "data", "kr16_2", "out", {"k": 1}, split=None, report=False) == {"workflow": name}
    assert seen == [(("data", "kr16_2", "out", {"k": 1}), {"split": None, "report": False})]


def test_run_refuses_an_unknown_workflow() -> None:
    with pytest.raises(ConfigError, match=r"unknown workflow 'thermic'.*'geometric'"):
        workflows.run("thermic", "data", "kr16_2", "out")


def test_a_workflow_needs_a_folder_or_a_campaign(tmp_path) -> None:
    with pytest.raises(ConfigError, match="data_dir"):
        workflows.run("geometric", None, "kr16_2", tmp_path)


def test_run_by_name_writes_what_the_module_writes(tmp_path) -> None:
    from robocal.cli import main
    from robocal.workflows import geometric

    data = tmp_path / "data"
    assert main(["simulate", "geometric", "n_poses=30", "n_validation_poses=8", "--out", str(data), "--seed", "2"]) == 0
    by_name = workflows.run("geometric", data, "kr16_2", tmp_path / "a", {"noise_mm": 0.02}, report=False)
    direct = geometric.run(data, "kr16_2", tmp_path / "b", {"noise_mm": 0.02}, report=False)
    assert by_name["fit"]["rms_position_mm"] == direct["fit"]["rms_position_mm"]
    assert json.loads((tmp_path / "a" / "summary.json").read_text()).keys() == by_name.keys() == direct.keys()
    assert (tmp_path / "a" / "residuals.csv").read_bytes() == (tmp_path / "b" / "residuals.csv").read_bytes()
