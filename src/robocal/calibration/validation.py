"""Errors of a calibrated model on a campaign's validation rows (:func:`validate`, :func:`validate_rows`)."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.calibration.result import CalibrationResult
from robocal.errors import ConfigError
from robocal.kinematics.chain import fk
from robocal.kinematics.transforms import inv_transform, kabsch, quat_to_matrix
from robocal.metrics import ErrorStats, orientation_errors_deg

if TYPE_CHECKING:
    from robocal.data.campaign import Campaign


@dataclass(frozen=True, eq=False)
class Validation(Mapping[str, Any]):
    """Errors of a model on a campaign's validation rows (:func:`validate_rows`, :func:`validate`).

    stats : over the rows evaluated (``stats.n`` of them; the registration rows of a station or a target not
    seen in calibration are left out); errors_mm : (m, 3) prediction - measurement of every validation row;
    kept_rows : (m,) the rows evaluated; tool_source / tools_mm / station_source : where each target's tool
    offset and each station's frame came from (``station_source`` None when every station is the calibration's).

    Read as a mapping it is the record ``robocal.validate`` has always returned (``v["mean_position_mm"]``,
    ``v["errors_mm"]`` ...; :meth:`to_dict`); :meth:`record` is that record without the arrays (summary.json).
    """

    stats: ErrorStats
    errors_mm: np.ndarray | None = None
    kept_rows: np.ndarray | None = None
    tool_source: dict[str, str] = field(default_factory=dict)
    tools_mm: dict[str, list[float]] = field(default_factory=dict)
    station_source: dict[str, str] | None = None
    per_station: dict[str, dict[str, Any]] | None = None  # with ``station_source``: each station's own figures

    @classmethod
    def none(cls) -> Validation:
        """No validation rows."""
        return cls(ErrorStats.of(np.zeros(0)))

    @property
    def n_rows(self) -> int:
        return self.stats.n

    def to_dict(self) -> dict[str, Any]:
        """The record (keys and order as the files have them; ``{"n_rows": 0}`` without validation rows)."""
        if self.errors_mm is None:
            return {"n_rows": 0}
        out: dict[str, Any] = {
            "n_rows": self.n_rows,
            **self.stats.position(),
            "tool_source": self.tool_source,
            "tools_mm": self.tools_mm,
            "errors_mm": self.errors_mm,
            "kept_rows": self.kept_rows,
        }
        if self.station_source is not None:
            out["station_source"] = self.station_source
        if self.per_station is not None:
            out["per_station"] = self.per_station
        out.update(self.stats.orientation(("mean", "max", "rms")))
        return out

    def record(self) -> dict[str, Any]:
        """:meth:`to_dict` without the per-row arrays (``errors_mm``, ``kept_rows``)."""
        return {k: v for k, v in self.to_dict().items() if k not in ("errors_mm", "kept_rows")}

    def __getitem__(self, key: str) -> Any:
        return self.to_dict()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.to_dict())

    def __len__(self) -> int:
        return len(self.to_dict())


def determined_stations(stations: dict[str, np.ndarray], cal: Campaign) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """The calibration's stations whose frame its rows determine (at least 3 measured points not on one line),
    and why each other one is not: its validation rows are then registered on their own, as a station the
    calibration never saw (:func:`validate_rows`). A station with 1-2 calibration rows has a frame the fit cannot
    turn (its rotation eliminated, held at an arbitrary start): judged with it, its validation rows were metres off
    (a newcomer's campaign of 12 stations: mean 31.5 mm, max 1 990 mm, and no word of why)."""
    keep: dict[str, np.ndarray] = {}
    why: dict[str, str] = {}
    st = None if cal.station is None else np.asarray(cal.station).astype(str)
    for s, T in stations.items():
        pts = cal.p_mm if st is None else cal.p_mm[st == s]
        pts = np.unique(np.round(pts, 6), axis=0)
        # off one line: the points' second singular value (mm) clear of zero, absolutely and against the first
        sv = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False) if len(pts) >= 3 else np.zeros(2)
        if sv[1] > max(1.0, 1e-3 * float(sv[0])):
            keep[s] = T
        else:
            why[s] = f"its {len(pts)} calibration point(s) do not determine its frame (3 not on one line needed)"
    return keep, why


def validate(result: CalibrationResult, campaign: Campaign, x: np.ndarray | None = None) -> Validation:
    """Errors of the calibrated model on the campaign's validation rows (see :func:`validate_rows`)."""
    val = campaign.validation()
    if val.n_rows == 0:
        return Validation.none()
    model = result.model
    x = result.x if x is None else x
    eta = x[: model.chain.n_params]
    base_T_flange = fk(model.chain, val.q, eta)
    stations = {s: model.base_transform(x, k) for k, s in enumerate(model.station_names)}
    stations, why = determined_stations(stations, campaign.calibration())
    tools = {t: model.tools(x)[k] for k, t in enumerate(model.target_names)}
    tool_R = None
    if model.orientation:
        tool_R = {t: R for t, R in zip(model.target_names, model.tool_rotations(x), strict=True)}
    return validate_rows(val, base_T_flange, stations, tools, tool_R, why=why)


def validate_rows(
    val: Campaign,
    base_T_flange: np.ndarray,
    stations: dict[str, np.ndarray],
    tools: dict[str, np.ndarray],
    tool_R: dict[str, np.ndarray] | None = None,
    dp_mm: np.ndarray | None = None,
    why: dict[str, str] | None = None,
) -> Validation:
    """Errors of a model's predictions on validation rows, with the tool and station handling every caller
    shares (geometric calibration and discovery alike).

    base_T_flange : (m, 4, 4) the model's flange pose of every validation row in the robot base frame;
    stations : {station: tracker_T_base} of the calibration; tools : {target: (3,) flange offset};
    tool_R : {target: (3, 3)} with orientation data, else None; dp_mm : (m, 3) a displacement the model adds
    to each predicted point (tracker frame; e.g. a parameter drift modelled to first order), or None.

    A validation station the calibration never saw is registered (rigidly, Kabsch) on every other pose of its
    rows (the 1st, 3rd, ... in file order) and evaluated on the others; those registration rows are left out
    of the statistics. A validation target not seen in calibration takes its tool offset from its own row at
    all-zero joints when there is one (that row is then left out of the statistics); otherwise its offset is
    fitted with the robot fixed on every other pose of its rows and judged on the others (scored on the rows it was
    fitted to, a row moved by 5 mm showed 0.000 mm). The result says which. ``why``: stations the calibration
    measured but whose frame its rows do not determine (:func:`determined_stations`), handled as never seen. A
    station too small to register is left out of the statistics, saying so (it stopped the whole run).
    """
    m = val.n_rows
    keep = np.ones(m, dtype=bool)
    assert val.station is not None
    T_st = np.zeros((m, 4, 4))
    station_source: dict[str, str] = {}
    for s in val.station_names:
        rows = np.flatnonzero(val.station == s)
        if s in stations:
            T_st[rows] = stations[s]
            station_source[s] = "calibration"
            continue
        poses = list(dict.fromkeys(val.pose_id[rows].tolist()))
        reg_poses = set(poses[::2])
        known_rows = rows[np.isin(val.target[rows], list(tools))]
        reg = known_rows[np.isin(val.pose_id[known_rows], list(reg_poses))]
        seen = (why or {}).get(s)
        head = "not in calibration" if seen is None else f"in calibration, but {seen}"
        if len(reg) < 3 or len(poses) < 4:
            keep[rows] = False
            station_source[s] = (
                f"{head}; too few rows of calibrated targets to register it on half of its poses ({len(reg)} for "
                f"registration, {len(poses)} poses; need >= 3 and >= 4): its {len(rows)} row(s) not evaluated"
            )
            continue
        pts = np.stack([base_T_flange[i, :3, 3] + base_T_flange[i, :3, :3] @ tools[str(val.target[i])] for i in reg])
        T_st[rows] = kabsch(pts, val.p_mm[reg])
        keep[rows[np.isin(val.pose_id[rows], list(reg_poses))]] = False
        station_source[s] = (
            f"{head}: registered on {len(reg_poses)} of its {len(poses)} poses (every other pose in file order), "
            "evaluated on the others"
        )
    T_fl = T_st @ base_T_flange  # tracker_T_flange (m, 4, 4)
    pred = np.zeros((m, 3))
    tool_source: dict[str, str] = {}
    tools_used: dict[str, list[float]] = {}
    for name in val.target_names:
        rows = np.flatnonzero(val.target == name)
        if name in tools:
            t = np.asarray(tools[name], dtype=float)
            tool_source[name] = "calibration"
        else:
            zero = rows[np.all(np.abs(val.q[rows]) < 1e-12, axis=1)]
            if len(zero):
                r0 = zero[0]
                t = (inv_transform(T_fl[r0]) @ np.append(val.p_mm[r0], 1.0))[:3]
                keep[r0] = False
                tool_source[name] = f"zero-joint row {int(val.row_number[r0])} (left out of the statistics)"
            else:  # fitted on every other pose of its rows, judged on the others (never on the rows it was fitted to)
                poses = list(dict.fromkeys(val.pose_id[rows].tolist()))
                fit_rows = rows[np.isin(val.pose_id[rows], poses[::2])]
                A = T_fl[fit_rows, :3, :3].reshape(-1, 3)
                b = (val.p_mm[fit_rows] - T_fl[fit_rows, :3, 3]).reshape(-1)
                t = np.linalg.lstsq(A, b, rcond=None)[0]
                keep[fit_rows] = False
                tool_source[name] = (
                    f"fitted with the robot fixed on {len(poses[::2])} of its {len(poses)} validation poses (every "
                    "other pose in file order), judged on the others"
                    if len(poses) > 1
                    else "fitted with the robot fixed on its one validation pose: not evaluated"
                )
        tools_used[name] = [float(v) for v in t]
        pred[rows] = T_fl[rows, :3, 3] + np.einsum("mij,j->mi", T_fl[rows, :3, :3], t)
    if dp_mm is not None:
        pred = pred + dp_mm
    err = pred - val.p_mm
    if not keep.any():
        raise ConfigError(f"no validation row of {val.poses_file} is left to evaluate after registration")
    eo = None
    if val.quat is not None and tool_R is not None and all(t in tools for t in val.target_names):
        R = T_fl[:, :3, :3] @ np.stack([tool_R[str(t)] for t in val.target])
        eo = orientation_errors_deg(R[keep], quat_to_matrix(val.quat[keep]))
    shown = len(station_source) > 1 or any(v != "calibration" for v in station_source.values())
    return Validation(
        ErrorStats.of(err[keep], eo), err, keep, tool_source, tools_used, station_source if shown else None,
        _per_station(val, keep, err) if shown else None,
    )  # fmt: skip


def _per_station(val: Campaign, keep: np.ndarray, err: np.ndarray) -> dict[str, dict[str, Any]] | None:
    """Each station's own figures on its rows evaluated: a station the calibration never saw is a new session, its
    figure not to be read in a mean with the calibration's own (newcomer pass 13: 0.13 mm of 0.025 within and 0.24
    in the other). None with fewer than two stations evaluated."""
    out = {}
    for s in val.station_names:
        k = keep & (val.station == s)
        if np.any(k):
            out[s] = {"n_rows": int(np.sum(k)), **ErrorStats.of(err[k]).position()}
    return out if len(out) > 1 else None
