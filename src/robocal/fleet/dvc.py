"""A DVC pipeline over a fleet folder: ``foreach`` over the robots, then one fleet stage.

Why ``foreach`` (and not ``matrix``, nor one stage that fans out): the unit DVC should re-run is a *robot* —
its folder is what changes when a campaign is added — and the robots are a plain list, not a cross product
(``matrix`` multiplies lists, e.g. robots × settings; campaigns differ from robot to robot, so robot × campaign is
no product). One ``calibrate@<serial>`` stage per robot depends on ``<serial>/`` only, so ``dvc repro`` after a new
campaign re-runs that robot's stage and the fleet stage, nothing else; its outputs are ``persist``-ed, so inside
the stage robocal's own cache computes only the new campaign. One stage that fans out (``robocal fleet`` on Ray)
would re-run as a whole whenever any robot changes (its cache would still skip the unchanged campaigns, but DVC
would show the whole fleet as changed); that stage is the right tool for the first run of a big fleet on a
cluster, the ``foreach`` pipeline for the months after. DVC runs the stages one after the other.

:func:`write_dvc_pipeline` writes ``dvc.yaml`` into the fleet folder (rerun it when robots are added).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from robocal.io import write_text


def pipeline(serials: Sequence[str], out: str = "out", extra: Sequence[str] = ()) -> dict[str, Any]:
    """The ``dvc.yaml`` mapping for a fleet whose robots are ``serials`` (paths relative to the fleet folder)."""
    tail = "".join(f" {a}" for a in extra)
    return {
        "stages": {
            "calibrate": {
                "foreach": list(serials),
                "do": {
                    "cmd": f"robocal fleet . --out {out} --robot ${{item}} --engine local --no-progress{tail}",
                    "deps": ["${item}"],
                    "outs": [{f"{out}/robots/${{item}}": {"persist": True}}],
                },
            },
            "fleet": {
                "cmd": f"robocal fleet . --out {out} --engine local --no-progress{tail}",
                "deps": [f"{out}/robots/{s}" for s in serials],
                "outs": [f"{out}/fleet.json", f"{out}/report.html"],
            },
        }
    }


def write_dvc_pipeline(fleet_dir: str | Path, out: str = "out", extra: Sequence[str] = ()) -> Path:
    """Write ``FLEET_DIR/dvc.yaml`` for the robots the folder holds now; returns its path."""
    from robocal.fleet.layout import read_fleet

    fleet = read_fleet(fleet_dir)
    text = (
        "# robocal fleet pipeline, written by `robocal fleet FLEET_DIR --write-dvc`: one stage per robot (foreach),\n"
        "# then the fleet files. Rewrite it when robots are added. `dvc repro` re-runs only the robots that changed.\n"
        + yaml.safe_dump(pipeline([r.serial for r in fleet.robots], out, extra), sort_keys=False)
    )
    return write_text(fleet.path / "dvc.yaml", text)
