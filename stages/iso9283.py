"""iso9283: the ISO 9283 pose characteristics of the campaign when it is an ISO test (robocal.iso9283).

Reads ``robot`` and ``iso9283``; the interim campaign and a calibration (``iso9283.calibration``, default the
geometric stage's ``calibration.json``: the tracker registered to the robot base by it; "after" is that
calibration's predicted error removed, labelled as predicted). A campaign without the ISO columns
(``iso_pose``, ``cycle``, ``cmd_x_mm`` .. ``cmd_z_mm``) skips, saying so: the default campaign is a calibration
campaign, not an ISO test. Writes ``reports/iso9283/``
(iso9283.json, iso9283_after.json, report.html: the certificate) and metrics (AP_p and RP_l before / after).

    dvc exp run iso9283 -S data.campaign=/path/to/iso_test -S iso9283.calibration=/path/to/calibration.json
"""

from __future__ import annotations

from typing import Any

from common import Context, Metrics, Skipped, Stage, run

STAGE = Stage(
    name="iso9283",
    params=("robot", "iso9283"),
    out="reports/iso9283",
    metrics="reports/metrics/iso9283.json",
    plots="reports/plots/iso9283",
)
#: The stage's inputs: the prepare stage's interim copy of the campaign and the geometric calibration.
INPUT = "data/interim"
CALIBRATION = "reports/geometric/calibration.json"
#: The columns that make a campaign an ISO test.
ISO_REQUIRED = ("iso_pose", "cycle", "cmd_x_mm", "cmd_y_mm", "cmd_z_mm")


def metrics_of(before: dict[str, Any], after: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for label, res in (("before", before), ("after", after)):
        for p in res["poses"]:
            out[f"{label}_{p['pose']}_AP_p_mm"] = p["AP_p_mm"]
            out[f"{label}_{p['pose']}_RP_l_mm"] = p["RP_l_mm"]
    return out


def compute(ctx: Context) -> Metrics | Skipped:
    import pyarrow.parquet as pq

    columns = set(pq.read_schema(ctx.path(f"{INPUT}/poses.parquet")).names)
    missing = [c for c in ISO_REQUIRED if c not in columns]
    if missing:
        return ctx.skip(f"the campaign is not an ISO 9283 test (no {', '.join(missing)} column): nothing to certify")
    from robocal.iso9283.run import run_iso9283
    from robocal.iso9283.settings import IsoSettings
    from robocal.robot import robot_from_dict

    robot = robot_from_dict(ctx.cfg["robot"], source="params: robot")
    settings = IsoSettings.from_mapping(ctx.cfg["iso9283"])
    cal = ctx.path(settings.calibration or CALIBRATION)
    res = run_iso9283(ctx.path(INPUT), robot, cal, ctx.out, settings=settings)
    for name in ("report.html", "iso9283.json", "iso9283_after.json"):
        ctx.artifact(ctx.out / name)
    before, after = res.before.to_dict(), res.after.to_dict()
    headline = {
        "iso_AP_p_max_mm": max(p["AP_p_mm"] for p in before["poses"]),
        "iso_RP_l_max_mm": max(p["RP_l_mm"] for p in before["poses"]),
        f"iso_AP_p_max_{res.after_kind}_after_mm": max(p["AP_p_mm"] for p in after["poses"]),
    }
    return Metrics(headline, metrics_of(before, after))


if __name__ == "__main__":
    run(STAGE, compute)
