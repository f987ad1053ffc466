"""``robocal calibrate DATA_DIR --robot NAME_OR_YAML --out DIR [key=value ...]``."""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from robocal.commands import ROBOT_HELP, parse_overrides
from robocal.config import unknown_choice, unknown_setting
from robocal.errors import ConfigError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("data_dir", help="campaign directory in the data contract")
    p.add_argument("--robot", required=True, help=ROBOT_HELP)
    p.add_argument(
        "--out", required=True, help="output directory: calibration.json, residuals.csv, summary.json, report.html"
    )
    p.add_argument("--no-report", action="store_true", help="skip the HTML report")
    p.add_argument(
        "overrides",
        nargs="*",
        help="calibration settings key=value, e.g. noise_mm=0.02 'fixed=[beta2]' split.method=none; "
        "optimizer=<name> (conf/optimizer/<name>.yaml: gn, lm, ipopt, igoa, goa, woa) and optimizer.<key>=<value>, "
        "as in the pipeline",
    )


#: The optimizer configs (Hydra group conf/optimizer/), shared with the pipeline.
OPTIMIZER_DIR = Path(__file__).resolve().parents[3] / "conf" / "optimizer"


def optimizer_config(value: Any, conf_dir: Path = OPTIMIZER_DIR) -> dict[str, Any] | None:
    """The optimizer config of ``optimizer=<name>`` / ``optimizer.<key>=<value>`` overrides (None: none given).

    ``value`` is a name (``"woa"``) or a mapping of keys; a mapping without ``name`` changes ``lm`` (the
    pipeline's default). The named file's settings come first, the given keys override them.
    """
    if value is None:
        return None
    keys = dict(value) if isinstance(value, dict) else {"name": value}
    name = keys.pop("name", "lm")
    path = conf_dir / f"{name}.yaml"
    if not isinstance(name, str) or not path.is_file():
        from robocal.optimizers.registry import aliases

        raise unknown_choice("optimizer", name, (p.stem for p in conf_dir.glob("*.yaml")), aliases())
    cfg = dict(yaml.safe_load(path.read_text(encoding="utf-8")) or {})
    unknown = sorted(set(keys) - set(cfg))
    if unknown:
        raise unknown_setting("optimizer", unknown[0], keys[unknown[0]], (k for k in cfg if k != "_target_"))
    cfg.update(keys)
    return cfg


#: the fit's own noise estimate over the noise it was judged against above which the console says the model misfits
MISFIT_HINT_RATIO = 2.0


def misfit_hint(noise: dict[str, Any]) -> str | None:
    """A line when the fit's residuals imply a noise well above the one the calibration was judged against (its
    ``fit.noise`` record): the geometric model misses an effect, or the instrument is noisier than set (newcomer
    pass 9: reduced chi² 47 and 7 683, status ok, nothing on the console)."""
    used = noise.get("used_mm")
    implied = ((noise.get("routes") or {}).get("fit") or {}).get("sigma_mm")
    if not used or not implied or implied < MISFIT_HINT_RATIO * used:
        return None
    return (
        f"misfit: the residuals imply a noise of {implied:.3g} mm per coordinate, {implied / used:.3g} times the "
        f"{used:.3g} mm judged against: the geometric model misses an effect (robocal discover looks for it) or the "
        "instrument is noisier than set (noise_mm)"
    )


def fit_line(summary: Mapping[str, Any], method: str) -> str:
    """The fit's console line: rows, RMS, parameters, iterations and the validation; on a robot on external axes
    the RMS said to be the arm's, beside the fit with the axes' errors whose validation the line gives (newcomer pass
    14: the arm's RMS and misfit verdict read beside the track model's validation)."""
    fit = summary["fit"]
    ax = summary.get("axes") or {}
    rms = f"RMS {fit['rms_position_mm']:.4f} mm"
    if ax.get("rms_position_mm") is not None:
        rms += f" (the arm alone; {float(ax['rms_position_mm']):.4f} with the axes' errors)"
    line = (
        f"fit ({method}): {fit['n_rows']} rows, {rms}, {summary['n_identified']} identified, "
        f"{len(summary['eliminated'])} eliminated, {fit['nit']} iterations in {fit['wall_time_s']:.3f} s"
    )
    v = summary.get("validation") or {}
    if v.get("n_rows"):
        line += f"; validation mean {v['mean_position_mm']:.4f} / max {v['max_position_mm']:.4f} mm"
    return line


def station_lines(v: Mapping[str, Any]) -> list[str]:
    """The validation's stations each judged otherwise than by the calibration's frame (a new session: its tracker
    registered on its own rows), and with several stations each one's own figure beside the mean over them."""
    per = v.get("per_station") or {}
    out = []
    for st, how in (v.get("station_source") or {}).items():
        fig = f"mean {per[st]['mean_position_mm']:.4f} mm on {per[st]['n_rows']} rows" if st in per else ""
        if how != "calibration":
            out.append(f"  validation station {st}: {how}" + (f"; {fig} (a new session)" if fig else ""))
        elif fig:
            out.append(f"  validation station {st}: calibrated there; {fig} (within the session)")
    return out


def run(args: argparse.Namespace) -> int:
    from robocal.workflows import geometric

    # optimizer=<name> and optimizer.<key>=<value> combine (the name is not a mapping parse_overrides can nest)
    named = [a.split("=", 1)[1] for a in args.overrides or [] if a.startswith("optimizer=")]
    ov = parse_overrides([a for a in args.overrides or [] if not a.startswith("optimizer=")])
    split = ov.pop("split", None)
    keys = ov.pop("optimizer", None)
    if keys is not None and not isinstance(keys, dict):
        raise ConfigError(f"The setting 'optimizer' must be a name or optimizer.<key>=<value>. Got {keys!r} instead.")
    optimizer = optimizer_config({**(keys or {}), "name": named[-1]} if named else keys)
    from robocal.calibration.solve import GRADIENT_KEYS, is_gradient

    if optimizer is not None and is_gradient(optimizer):
        # calibrate()'s stopping rules come from the optimizer config; calibration overrides of them win
        optimizer.update({key: ov[key] for key in GRADIENT_KEYS if key in ov})
    summary = geometric.run(
        args.data_dir, args.robot, args.out, ov, split=split, report=not args.no_report, optimizer=optimizer
    )
    fit = summary["fit"]
    print(fit_line(summary, (optimizer or {}).get("name", "lm")))
    for text in station_lines(summary.get("validation") or {}):
        print(text)
    from robocal.identification.robust import outlier_line

    print(outlier_line(fit.get("outliers", []), fit.get("n_rows_total")))
    hint = misfit_hint(fit.get("noise") or {})
    if hint:  # on a robot on external axes, of the arm's fit (the axes' errors are the line 'axes:' below)
        print(hint + (" (the arm's fit, without the axes' errors along the travel)" if "axes" in summary else ""))
    if fit.get("systematic_misfit"):
        from robocal.identification import misfit

        print(misfit.line(fit["systematic_misfit"]))
    if "axes" in summary:  # a track's or a column's own errors along the travel (robocal.calibration.axes)
        ax = summary["axes"]
        terms = sorted({t["name"].rsplit("_P", 1)[0] for t in ax["terms"]})
        v = ax["validation"]
        line = (f"axes: order {ax['order']} (cross-validated), {len(ax['terms'])} terms of {', '.join(terms)}" if terms
                else f"axes: order {ax['order']} (cross-validated): no error along the travel is fitted")  # fmt: skip
        if v.get("n_rows"):
            line += f"; validation mean {v['mean_position_mm']:.4f} / max {v['max_position_mm']:.4f} mm"
            if "without_axes_mean_mm" in v:
                line += f" (the arm's calibration alone {v['without_axes_mean_mm']:.4f})"
        print(line)
    design = fit.get("configurations")
    if isinstance(design, dict) and design.get("enough"):
        from robocal.identification.acceptance import thin_campaign, thin_is_warned

        if not thin_is_warned(design):  # recorded, not warned about: said here
            print(f"configurations: {thin_campaign(design)}")
    problems = summary.get("problems", [])
    for text in problems:
        print(f"robocal calibrate: FAILED: {text}")
    for text in summary.get("warnings", []):  # status "warning": usable with care, exit 0
        print(f"robocal calibrate: WARNING: {text}")
    written = [*geometric.OUTPUTS, *([] if args.no_report else [geometric.REPORT])]
    print(f"wrote {', '.join(written)} in {args.out}")
    return 1 if problems else 0
