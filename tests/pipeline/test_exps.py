"""`make exps` on an 80-column terminal (issue 30 item 10): one short table, what differs under it."""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

from robocal.exps import rows_of, table

REPO = Path(__file__).resolve().parents[2]


def _data(campaign: str, robot: str, fit: float, thermal: str) -> dict[str, Any]:
    params = {
        "robot": {"name": robot, "joints": [{"a_mm": 0.0}], "n_joints": 6},
        "scenario": {"name": "thermal", "noise_mm": 0.015},
        "data": {"campaign": campaign},
        "optimizer": {"name": "lm", "max_iter": 200},
    }
    metrics = {
        "reports/metrics/geometric_fit.json": {
            "data": {"geometric_fit": "ok", "fit_rms_mm": fit, "val_mean_mm": 0.0867}
        },
        "reports/metrics/thermal_fit.json": {"data": {"thermal_fit": thermal}},
        "reports/metrics/validate.json": {"data": {"validate": "ok", "comp_proposed_mean_mm": 0.0291}},
        "reports/metrics/discover.json": {"data": {"discover": "ok", "disc_rms_mm": 0.0246, "disc_named": 1}},
        "reports/metrics/prepare.json": {"data": {"prepare": "ok", "rows": 315, "val_rows": 105}},
    }
    return {"rev": "x", "params": {"params.yaml": {"data": params}}, "metrics": metrics}


def _show() -> list[dict[str, Any]]:
    """`dvc exp show --json` of DVC 3: the workspace, the baseline commit and its experiments."""
    base = _data("data/raw/default", "kr16_2", 0.092545, "ok")
    ur10 = _data("/home/someone/plant-data/robots/ur10-ipa-cell-4/", "ur10", 0.1105, "skipped")
    abb = copy.deepcopy(_data("../shared/data/abb-irb120", "abb_irb120", 0.1502, "skipped"))
    abb["params"]["params.yaml"]["data"]["optimizer"]["max_iter"] = 400
    return [
        {"rev": "workspace", "name": None, "data": base, "error": None, "experiments": None},
        {
            "rev": "56716bc0aa",
            "name": "main",
            "data": base,
            "error": None,
            "experiments": [
                {
                    "name": "swank-bale-ur10-own-data",
                    "revs": [{"rev": "aa", "name": "swank-bale-ur10-own-data", "data": ur10}],
                },
                {"name": "tipsy-mole", "revs": [{"rev": "bb", "name": "tipsy-mole", "data": abb}]},
            ],
        },
    ]


def test_exps_fit_80_columns_and_say_what_differs() -> None:
    text = table(rows_of(_show()), width=80)
    lines = text.splitlines()
    assert max(len(x) for x in lines) <= 80, text
    head = lines[0].split()
    assert head[:5] == ["experiment", "fit", "val", "comp", "discover"]
    assert lines[1].split()[:2] == ["workspace", "0.0925"] and lines[3].startswith("swank-bale-ur10-own-d…")
    assert "robot.name=ur10" in text and "data.campaign=/home/someone/plant-data/robots/ur10-ipa-cell-4/" in text
    assert "optimizer.max_iter=400" in text and "not ok: thermal_fit skipped" in text
    assert "scenario.noise_mm" not in text and "robot.n_joints" not in text and "robot.joints" not in text  # same


def test_make_exps_uses_it() -> None:
    assert "robocal.exps" in (REPO / "Makefile").read_text()
    out = subprocess.run(
        [sys.executable, "-m", "robocal.exps", "--width", "80"], input=json.dumps(_show()), capture_output=True,
        text=True, check=True,
    )  # fmt: skip
    assert out.stdout.splitlines()[0].startswith("experiment")
