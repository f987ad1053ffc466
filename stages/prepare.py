"""prepare: the data door. The campaign named by ``data.campaign`` is checked against the data contract
(robocal.data.read_campaign: every rule, errors naming file / row / column) and copied to ``data/interim/`` as
Parquet, in contract columns, with the calibration / validation split fixed (``split`` column), so every later
stage reads the same rows. ``data/interim/prepare.json`` says what the campaign has (temperatures, payload,
torques, currents, approach directions, orientations), which later stages use to decide whether they have
anything to do. The raw campaign is only read, never written.

Run on your own campaign: ``dvc exp run -S data.campaign=/path/to/campaign`` (and ``-S robot=<name>``).
"""

from __future__ import annotations

from common import Context, Metrics, Stage, run

STAGE = Stage(
    name="prepare",
    params=("data", "robot"),
    out="data/interim",
    metrics="reports/metrics/prepare.json",
)


def compute(ctx: Context) -> Metrics:
    import pandas as pd

    from robocal.data import SplitConfig, read_campaign
    from robocal.data.campaign import TEMPERATURE_TOLERANCE_S
    from robocal.io import atomic_write, display_path, write_json
    from robocal.pipeline import campaign_dir
    from robocal.robot import robot_from_dict

    src = campaign_dir(ctx.root, ctx.cfg)
    robot = robot_from_dict(ctx.cfg["robot"], source="params: robot")
    split = SplitConfig.from_mapping(ctx.get("data.split", None), "data.split")
    camp = read_campaign(
        src,
        robot,
        split=split,
        temperature_tolerance_s=float(
            ctx.get("data.temperature_tolerance_s", TEMPERATURE_TOLERANCE_S, types=(int, float))
        ),
    )
    # stale files of an earlier campaign (e.g. temperatures.parquet) must not survive into this one
    for old in ctx.out.glob("*.parquet"):
        old.unlink()
    frame = camp.to_frame()
    atomic_write(ctx.out / "poses.parquet", lambda p: frame.to_parquet(p, index=False))
    # the logged signals declared beside the campaign travel with its copy (robocal.logged_signals)
    if camp.signal_declarations:
        import yaml

        decl = {"signals": {d.name: d.to_dict() for d in camp.signal_declarations}}
        atomic_write(ctx.out / "signals.yaml", lambda p: p.write_text(yaml.safe_dump(decl, sort_keys=True)))
    else:
        (ctx.out / "signals.yaml").unlink(missing_ok=True)
    if camp.temperature_log is not None:
        log = camp.temperature_log
        tlog = pd.DataFrame(
            {
                "timestamp": pd.to_datetime(camp.t0) + pd.to_timedelta(log["t_s"].to_numpy(), unit="s"),
                **{c: log[c].to_numpy() for c in camp.sensor_names},
            }
        )
        atomic_write(ctx.out / "temperatures.parquet", lambda p: tlog.to_parquet(p, index=False))
    n_cal = int((camp.split == "calibration").sum())
    info = {
        "source": display_path(src),
        "robot": robot.name,
        "n_rows": camp.n_rows,
        "n_poses": len(set(camp.pose_id.tolist())),
        "n_calibration_rows": n_cal,
        "n_validation_rows": camp.n_rows - n_cal,
        "split_from_file": camp.split_from_file,
        "targets": list(camp.target_names),
        "sensors": list(camp.sensor_names),
        "has_orientation": camp.has_orientation,
        "has_temperatures": camp.has_temperatures,
        "has_payload": camp.has_payload,
        "has_torques": camp.has_torques,
        "has_currents": camp.has_currents,
        "has_directions": camp.has_directions,
        "duration_s": float(camp.timestamp_s.max()) if camp.n_rows else 0.0,
    }
    write_json(ctx.out / "prepare.json", info)
    details = {k: v for k, v in info.items() if isinstance(v, bool | int | float) and k != "split_from_file"}
    return Metrics({"rows": camp.n_rows, "val_rows": camp.n_rows - n_cal}, details)


if __name__ == "__main__":
    run(STAGE, compute)
