"""params.yaml is generated from conf/ (DVC's Hydra composition) and must stay in sync with it.

Compared byte for byte: `dvc exp run` rewrites params.yaml wholly from conf/ (OmegaConf.to_yaml of the
resolved composition), so any difference, even in formatting, would show up as a spurious params change in
`git diff` / `dvc params diff` the first time someone runs an experiment. The parsed comparison runs first
only to give a readable message when the *values* differ.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from dvc.utils.hydra import compose_and_dump

from robocal.errors import ConfigError
from robocal.pipeline import compose, get, load_params, params_text

REPO = Path(__file__).resolve().parents[2]


def test_params_yaml_is_in_sync_with_conf() -> None:
    current = (REPO / "params.yaml").read_text(encoding="utf-8")
    expected = params_text(REPO)
    assert yaml.safe_load(current) == yaml.safe_load(expected), "params.yaml values differ from conf/: make params"
    assert current == expected, "params.yaml is not byte-identical to the composition of conf/: make params"


def test_hydra_compose_api_matches_dvc_composition(tmp_path: Path) -> None:
    # what `dvc exp run` writes (DVC's own function) == what robocal composes with Hydra's compose API
    out = tmp_path / "params.yaml"
    compose_and_dump(out, str(REPO / "conf"), None, "config", str(REPO), ["optimizer=gn"])
    assert out.read_text(encoding="utf-8") == params_text(REPO, ["optimizer=gn"])


def test_conf_has_the_required_groups_and_one_campaign_value() -> None:
    cfg = compose(REPO)
    for group in ("robot", "optimizer", "scenario", "calibration"):
        assert group in cfg, group
    assert "hydra" not in cfg  # Hydra's own settings never reach params.yaml
    assert cfg["data"]["campaign"] == "data/raw/default"
    assert cfg["scenario"]["robot"] == cfg["robot"]["name"]  # the twin simulates the calibrated robot


@pytest.mark.parametrize("name", ["gn", "lm"])
def test_group_override_changes_only_its_section(name: str) -> None:
    base = compose(REPO)
    other = compose(REPO, [f"optimizer={name}"])
    assert other["optimizer"]["name"] == name
    assert {k: v for k, v in other.items() if k != "optimizer"} == {k: v for k, v in base.items() if k != "optimizer"}


def test_dvc_hydra_composition_is_enabled() -> None:
    text = (REPO / ".dvc" / "config").read_text()
    assert "[hydra]" in text and "enabled = true" in text


def test_load_params_and_get_name_the_missing_key(tmp_path: Path) -> None:
    p = tmp_path / "params.yaml"
    p.write_text("data:\n  campaign: x\n")
    with pytest.raises(ConfigError, match="'robot'"):
        load_params(p, ["data", "robot"])
    cfg = load_params(p, ["data"])
    assert get(cfg, "data.campaign") == "x"
    with pytest.raises(ConfigError, match=r"'data\.split\.method'"):
        get(cfg, "data.split.method")
    with pytest.raises(ConfigError, match=r"'data\.campaign' must be of type int"):
        get(cfg, "data.campaign", types=int)
