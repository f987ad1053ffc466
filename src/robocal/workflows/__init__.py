"""Workflows: a campaign directory in, result files out. Shared by the CLI and the pipeline stages.

Each end-to-end workflow is a module here with one ``run`` of one shape::

    run(data_dir, robot, out_dir, settings=None, *, split=None, campaign=None, report=True, **extras) -> dict

``data_dir``: the campaign folder (the data contract); ``robot``: a name, a YAML path or a
:class:`robocal.robot.RobotDescription`; ``settings``: the workflow's config mapping (its ``conf/`` group);
``split``: the split setting when the campaign has no ``split`` column; ``campaign``: an already read
campaign (then ``data_dir`` is not read); ``report``: write ``report.html``. The extras are keyword-only:
``geometric`` takes ``optimizer`` (a ``conf/optimizer`` config), ``thermal`` ``screen`` (the screening
settings, ``conf/screen``), ``compliance`` ``truth`` (a twin's truth). ``run`` writes into ``out_dir`` and
returns the summary.

:func:`run` runs one by name (:data:`NAMES`).
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from robocal.data.campaign import Campaign
    from robocal.robot import RobotDescription

#: The workflows, each the module ``robocal.workflows.<name>``.
NAMES = ("geometric", "thermal", "compliance", "discovery")


def run(
    name: str,
    data_dir: str | Path | None,
    robot: str | Path | RobotDescription,
    out_dir: str | Path,
    settings: Mapping[str, Any] | None = None,
    **kw: Any,
) -> dict[str, Any]:
    """Run the workflow ``name`` (one of :data:`NAMES`): ``robocal.workflows.<name>.run(data_dir, robot, out_dir,
    settings, **kw)``."""
    if name not in NAMES:
        from robocal.errors import ConfigError

        raise ConfigError(f"unknown workflow {name!r}; known: {list(NAMES)}")
    module = importlib.import_module(f"robocal.workflows.{name}")
    result: dict[str, Any] = module.run(data_dir, robot, out_dir, settings, **kw)
    return result


def robot_of(robot: str | Path | RobotDescription) -> RobotDescription:
    """The robot argument of a workflow: a description as is, else loaded (a conf/robot name or a YAML path)."""
    from robocal.robot import RobotDescription, load_robot

    return robot if isinstance(robot, RobotDescription) else load_robot(robot)


def campaign_of(
    data_dir: str | Path | None,
    robot: RobotDescription,
    split: Mapping[str, Any] | None,
    campaign: Campaign | None,
) -> Campaign:
    """The campaign argument of a workflow: ``campaign`` when given, else the one read from ``data_dir``."""
    if campaign is not None:
        return campaign
    from robocal.data.campaign import SplitConfig
    from robocal.data.contract import read_campaign
    from robocal.errors import ConfigError

    if data_dir is None:
        raise ConfigError("a workflow needs a campaign folder (data_dir) or a campaign")
    return read_campaign(data_dir, robot, split=SplitConfig.from_mapping(split))


__all__ = ["NAMES", "campaign_of", "robot_of", "run"]
