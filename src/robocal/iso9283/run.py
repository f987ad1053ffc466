"""``robocal iso9283``: evaluate an ISO test campaign before and after calibration, write the certificate.

Before: the test as measured, in the robot base frame. The tracker is registered to the base by axis circles
(``base_circles.csv`` beside the campaign's ``poses.csv``, :mod:`robocal.iso9283.base_frame`: the base the robot's
axes 1 and 2 define, found without the calibration) when the campaign has them, else by the calibration's
``tracker_T_base``; the certificate and ``iso9283.json`` (``frame``, ``figures_frame``) say which. After:

- measured, when the compensated test exists (``--after DIR``, or ``CAMPAIGN/after`` as ``robocal simulate
  iso9283 --bundle`` writes it): the same evaluation of that campaign;
- predicted otherwise (real data measured once): :func:`robocal.iso9283.campaign.predicted_after`, the
  calibrated model's predicted error removed from every attained pose -- labelled as predicted.

Writes ``iso9283.json`` (before), ``iso9283_after.json`` (the same keys) and ``report.html`` into ``out``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from robocal.errors import ConfigError, DataError
from robocal.io import display_path, write_json
from robocal.iso9283.analysis import IsoResult, evaluate
from robocal.iso9283.base_frame import FILE as BASE_CIRCLES
from robocal.iso9283.base_frame import CircleRegistration, register_by_circles
from robocal.iso9283.campaign import predicted_after, read_iso
from robocal.iso9283.outcome import IsoRun
from robocal.iso9283.settings import IsoSettings
from robocal.kinematics.transforms import rpy_from_matrix
from robocal.robot import RobotDescription


def run_iso9283(
    campaign: str | Path,
    robot: str | Path | RobotDescription,
    calibration: str | Path,
    out: str | Path,
    after: str | Path | None = None,
    settings: IsoSettings | None = None,
    report: bool = True,
) -> IsoRun:
    from robocal.calibration.load import load_calibration
    from robocal.data import read_campaign
    from robocal.robot import load_robot

    st = settings or IsoSettings()
    rob = robot if isinstance(robot, RobotDescription) else load_robot(robot)
    cal_path = Path(calibration)
    if not cal_path.is_file():
        raise ConfigError(f"calibration file {cal_path} does not exist (robocal calibrate writes calibration.json)")
    cal = load_calibration(json.loads(cal_path.read_text(encoding="utf-8")), rob)
    camp = read_campaign(campaign, rob, {"method": "none"})
    reg = _circles(camp, rob)
    iso = read_iso(camp, cal, st.analysis.target, None if reg is None else reg.tracker_T_base)
    before = evaluate(iso.test, st.analysis)
    after_dir = Path(after) if after is not None else Path(campaign) / "after"
    if after is not None or (after_dir / "poses.csv").is_file() or (after_dir / "poses.parquet").is_file():
        camp_a = read_campaign(after_dir, rob, {"method": "none"})
        reg_a = _circles(camp_a, rob) or reg  # the after test's own circles, else the before's (the same tracker)
        iso_a = read_iso(camp_a, cal, iso.target, None if reg_a is None else reg_a.tracker_T_base)
        res_after = evaluate(iso_a.test, st.analysis)
        kind = "measured"
        after_src = camp_a.source
    else:
        res_after = evaluate(predicted_after(iso, cal), st.analysis)
        kind = "predicted"
        after_src = None
    T = cal.tracker_T_base if reg is None else reg.tracker_T_base
    frame: dict[str, Any] = {"name": "robot base"}
    if reg is None:
        frame["method"] = "calibration"
        frame["registration"] = (
            f"tracker_T_base of {display_path(cal_path)} (the measured points taken to the base by it); no "
            f"{BASE_CIRCLES} beside the campaign"
        )
        frame["figures_frame"] = (
            f"the base frame of the calibration {display_path(cal_path)}: its tracker_T_base, fitted with the model "
            "(joint 1's parameters that the base absorbs held at nominal, as calibration.json's 'eliminated' lists), "
            "so the base the robot's axes define as the calibration sees them; not measured independently (measure "
            f"axis circles, {BASE_CIRCLES}, for that)"
        )
    else:
        c1, c2 = reg.circles[1], reg.circles[2]
        frame["method"] = "axis circles"
        frame["registration"] = (
            f"circle fits to {display_path(reg.file)}: axis 1 ({c1.n} points over {c1.span_deg:.0f} deg, rms "
            f"{c1.rms_mm:.3f} mm), axis 2 ({c2.n} points over {c2.span_deg:.0f} deg, rms {c2.rms_mm:.3f} mm); "
            "independent of the calibration"
        )
        frame["circles"] = reg.info()
        frame["figures_frame"] = (
            "the robot base its axes define: z along axis 1, x and the origin from axis 2 where the robot "
            f"description's nominal axes put them (the tracker registered by axis circles, {BASE_CIRCLES})"
        )
    frame.update(
        {
            "tracker_T_base_xyz_mm": T[:3, 3].tolist(),
            "tracker_T_base_rpy_deg": np.rad2deg(rpy_from_matrix(T[:3, :3])).tolist(),
            "angles": "a, b, c: rotations about the base x, y, z axes, R = Rz(c) Ry(b) Rx(a), deg",
            "target": iso.target,
        }
    )
    before = _with_frame(before, {**frame, "campaign": camp.source, "kind": "measured (before calibration)"})
    after_label = (
        f"measured after compensation ({after_src})"
        if kind == "measured"
        else "predicted: the calibrated model's predicted error removed from the measured poses"
    )
    res_after = _with_frame(res_after, {**frame, "campaign": after_src or camp.source, "kind": after_label})
    info = {
        "robot": rob.name,
        "calibration": display_path(cal_path),
        "campaign": camp.source,
        "date": str(camp.t0.strftime("%Y-%m-%d")),
        "rows_in_file": int(camp.n_rows),
        "rows_of_target": len(iso.rows),
        "after_kind": kind,
    }
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_json(out_dir / "iso9283.json", before.to_dict())
    write_json(out_dir / "iso9283_after.json", res_after.to_dict())
    result = IsoRun(before, res_after, kind, iso, st, info)
    if report:
        from robocal.iso9283.report import write_report

        write_report(result, out_dir / "report.html")
    return result


def _circles(camp: Any, rob: RobotDescription) -> CircleRegistration | None:
    """The axis-circle registration of the campaign's tracker (``base_circles.csv`` beside its poses file), or None;
    a campaign measured from several tracker stations is refused with circles (they register one)."""
    path = Path(camp.poses_file).parent / BASE_CIRCLES
    if not path.is_file():
        return None
    stations = sorted(set(map(str, camp.station))) if camp.station is not None else []
    if len(stations) > 1:
        raise DataError(
            f"{BASE_CIRCLES} registers one tracker station; the campaign has {stations}",
            file=camp.poses_file,
            column="station",
        )
    return register_by_circles(path, rob)


def _with_frame(res: IsoResult, frame: dict[str, Any]) -> IsoResult:
    from dataclasses import replace

    return replace(res, frame={**frame, **res.frame})


__all__ = ["IsoRun", "run_iso9283"]
