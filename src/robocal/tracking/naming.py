"""How a run is named: ``<stage> · <campaign> · <experiment>``, and how a skipped stage's run says so."""

from __future__ import annotations

import os
from pathlib import Path

#: what joins the parts of a run's name: ``<stage> · <campaign> · <experiment>``
NAME_SEP = " · "
#: The MLflow run status of a skipped stage: FINISHED -- the stage ended as it should, having nothing to do (KILLED
#: showed a red cross, as if it had failed). What says "skipped" is the run's name, ``<stage> (skipped) · ...``, and
#: its tags: ``robocal.status = skipped`` (a column of the runs table :func:`set_runs_view` opens) and
#: ``robocal.skipped = <reason>``.
SKIPPED_STATUS = "FINISHED"


def campaign_label(campaign: str | None, scenario: str | None = None) -> str:
    """How a run names its campaign: the folder's name (``abb-irb120`` for ``../shared/data/abb-irb120``), or
    ``twin <scenario>`` for the twin's default campaign (``data/raw/default``)."""
    if not campaign:
        return f"twin {scenario}" if scenario else "no campaign"
    name = Path(str(campaign).rstrip("/")).name or str(campaign)
    if Path(str(campaign)).as_posix().rstrip("/").endswith("data/raw/default") and scenario:
        return f"twin {scenario}"
    return name


def run_title(stage: str, campaign: str, experiment: str | None = None) -> str:
    """``<stage> · <campaign> · <experiment>``: the DVC experiment (``$DVC_EXP_NAME``) when DVC runs one, else
    ``experiment`` (e.g. a Hydra job's overrides), else ``workspace`` (a plain ``dvc repro``)."""
    exp = os.environ.get("DVC_EXP_NAME") or experiment or "workspace"
    return NAME_SEP.join((stage, campaign, exp))


def skipped_title(name: str) -> str:
    """``compliance_fit · twin thermal · workspace`` -> ``compliance_fit (skipped) · twin thermal · workspace``."""
    stage, sep, rest = name.partition(NAME_SEP)
    return name if stage.endswith("(skipped)") else f"{stage} (skipped){sep}{rest}"
