"""Evaluate an ISO 9283 pose test: the rows of a campaign (base frame) -> the characteristics per pose.

:class:`IsoTest` holds the rows (attained and commanded poses in the robot base frame, the pose label, cycle,
approach, time, file row); :func:`evaluate` applies the stated gross-error rule per pose and approach, then
the formulas of :mod:`robocal.iso9283.characteristics`, and returns an :class:`IsoResult`.

Which rows give which characteristic:

- AP, RP (position and orientation), AD / RD and the drift use the cycles of one approach direction (the
  standard's unidirectional test; ``analysis.ap_approach``, default the first approach in the file);
- vAP uses every approach of a pose that has cycles from at least two directions.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from robocal.iso9283 import characteristics as ch
from robocal.iso9283.settings import AnalysisConfig


@dataclass(frozen=True)
class IsoTest:
    """The rows of an ISO pose test, robot base frame.

    pose : (m,) str label; cycle : (m,) int >= 1; approach : (m,) str; p_mm : (m, 3) attained position;
    cmd_mm : (m, 3) commanded position; rpy_deg / cmd_rpy_deg : (m, 3) attained / commanded angles a, b, c
    (rotations about base x, y, z; ``R = Rz(c) Ry(b) Rx(a)``) or None; t_s : (m,) seconds; row : (m,) the row in
    the file (header = 1); file : the file read.
    """

    pose: np.ndarray
    cycle: np.ndarray
    approach: np.ndarray
    p_mm: np.ndarray
    cmd_mm: np.ndarray
    t_s: np.ndarray
    row: np.ndarray
    rpy_deg: np.ndarray | None = None
    cmd_rpy_deg: np.ndarray | None = None
    file: str = ""

    @property
    def poses(self) -> list[str]:
        return list(dict.fromkeys(self.pose.tolist()))

    @property
    def approaches(self) -> list[str]:
        return list(dict.fromkeys(self.approach.tolist()))


@dataclass(frozen=True)
class PoseResult:
    """The characteristics of one test pose (mm, deg); ``deviations_mm`` (n, 3): each used cycle minus the
    barycentre (for the scatter plot)."""

    pose: str
    n_cycles: int
    approach: str
    commanded_mm: np.ndarray
    barycentre_mm: np.ndarray
    AP_p_mm: float
    AP_xyz_mm: np.ndarray
    RP_l_mm: float
    l_bar_mm: float
    S_l_mm: float
    deviations_mm: np.ndarray
    AP_abc_deg: np.ndarray | None = None
    RP_abc_deg: np.ndarray | None = None
    dAP_p_mm: float | None = None
    dRP_l_mm: float | None = None
    drift_span_min: float | None = None

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "pose": self.pose,
            "n_cycles": self.n_cycles,
            "approach": self.approach,
            "AP_p_mm": self.AP_p_mm,
            "AP_x_mm": float(self.AP_xyz_mm[0]),
            "AP_y_mm": float(self.AP_xyz_mm[1]),
            "AP_z_mm": float(self.AP_xyz_mm[2]),
            "RP_l_mm": self.RP_l_mm,
            "l_bar_mm": self.l_bar_mm,
            "S_l_mm": self.S_l_mm,
            "commanded_mm": self.commanded_mm.tolist(),
            "barycentre_mm": self.barycentre_mm.tolist(),
        }
        if self.AP_abc_deg is not None and self.RP_abc_deg is not None:
            for k, c in enumerate("abc"):
                d[f"AP_{c}_deg"] = float(self.AP_abc_deg[k])
            for k, c in enumerate("abc"):
                d[f"RP_{c}_deg"] = float(self.RP_abc_deg[k])
        if self.dAP_p_mm is not None:
            d["dAP_p_mm"] = self.dAP_p_mm
            d["dRP_l_mm"] = self.dRP_l_mm
            d["drift_span_min"] = self.drift_span_min
        return d


@dataclass(frozen=True)
class IsoResult:
    """The characteristics of a test: per pose, vAP per pose, AD / RD of the distance pair, the rows left out."""

    poses: list[PoseResult]
    vAP_p_mm: dict[str, float]
    AD_p_mm: float | None
    RD_l_mm: float | None
    distance_pair: tuple[str, str] | None
    left_out: list[dict[str, Any]]
    frame: dict[str, Any] = field(default_factory=dict)

    def pose(self, label: str) -> PoseResult:
        return next(p for p in self.poses if p.pose == label)

    def to_dict(self) -> dict[str, Any]:
        """``iso9283.json``: exactly the keys poses, vAP_p_mm, AD_p_mm, RD_l_mm, frame, left_out and
        figures_frame (the sentence saying which base frame the figures are in; ``frame`` has the details)."""
        frame = dict(self.frame)
        frame["distance_pair"] = None if self.distance_pair is None else list(self.distance_pair)
        figures_frame = frame.pop("figures_frame", None)
        return {
            "poses": [p.to_dict() for p in self.poses],
            "vAP_p_mm": dict(self.vAP_p_mm),
            "AD_p_mm": self.AD_p_mm,
            "RD_l_mm": self.RD_l_mm,
            "frame": frame,
            "left_out": list(self.left_out),
            "figures_frame": figures_frame,
        }


GROSS_RULE = (
    "per pose and approach, a cycle is left out when its distance d to the coordinate-wise median of the 5 cycles "
    "around it exceeds median(d) + {k:g} x max(1.4826 x MAD(d), {floor:g} mm); one pass"
)


def evaluate(test: IsoTest, cfg: AnalysisConfig | None = None) -> IsoResult:
    """The ISO 9283 characteristics of ``test`` (see the module docstring for which rows give which)."""
    cfg = cfg or AnalysisConfig()
    approaches = test.approaches
    ap_approach = cfg.ap_approach if cfg.ap_approach is not None else approaches[0]
    if ap_approach not in approaches:
        from robocal.config import SettingError

        raise SettingError("analysis.ap_approach", f"is not an approach of the campaign ({approaches})", ap_approach)
    keep = np.ones(len(test.pose), dtype=bool)
    left_out: list[dict[str, Any]] = []
    rule = GROSS_RULE.format(k=cfg.gross_error_k, floor=cfg.gross_error_floor_mm)
    for pose in test.poses:
        for a in approaches:
            idx = np.flatnonzero((test.pose == pose) & (test.approach == a))
            if len(idx) < 3:
                continue
            idx = idx[np.argsort(test.cycle[idx], kind="stable")]
            bad = ch.gross_errors(test.p_mm[idx], cfg.gross_error_k, cfg.gross_error_floor_mm)
            med = np.median(test.p_mm[idx[~bad]], axis=0)
            for i in idx[bad]:
                keep[i] = False
                left_out.append(
                    {
                        "row": int(test.row[i]),
                        "pose": pose,
                        "cycle": int(test.cycle[i]),
                        "approach": a,
                        "distance_mm": float(np.linalg.norm(test.p_mm[i] - med)),
                        "reason": "gross error: " + rule,
                    }
                )
    left_out.sort(key=lambda r: r["row"])
    orient = test.rpy_deg is not None and test.cmd_rpy_deg is not None
    results: list[PoseResult] = []
    vap: dict[str, float] = {}
    for pose in test.poses:
        sel = np.flatnonzero((test.pose == pose) & (test.approach == ap_approach) & keep)
        sel = sel[np.argsort(test.cycle[sel], kind="stable")]
        if len(sel) < 2:
            continue
        p = test.p_mm[sel]
        cmd = test.cmd_mm[sel[0]]
        ap, apx = ch.pose_accuracy(p, cmd)
        rp, lbar, s = ch.pose_repeatability(p)
        bary = ch.barycentre(p)
        apa = rpa = None
        if orient:
            assert test.rpy_deg is not None and test.cmd_rpy_deg is not None
            apa = ch.orientation_accuracy(test.rpy_deg[sel], test.cmd_rpy_deg[sel[0]])
            rpa = ch.orientation_repeatability(test.rpy_deg[sel], test.cmd_rpy_deg[sel[0]])
        dap = drp = span = None
        g = cfg.drift_group_cycles
        t = test.t_s[sel]
        if len(sel) >= 2 * g and float(t[-1] - t[0]) > 0:
            first, last = p[:g], p[-g:]
            dap = abs(ch.pose_accuracy(first, cmd)[0] - ch.pose_accuracy(last, cmd)[0])
            drp = abs(ch.pose_repeatability(first)[0] - ch.pose_repeatability(last)[0])
            span = float((t[-g:].mean() - t[:g].mean()) / 60.0)
        results.append(
            PoseResult(
                pose=pose,
                n_cycles=len(sel),
                approach=ap_approach,
                commanded_mm=np.asarray(cmd, dtype=float),
                barycentre_mm=bary,
                AP_p_mm=ap,
                AP_xyz_mm=apx,
                RP_l_mm=rp,
                l_bar_mm=lbar,
                S_l_mm=s,
                deviations_mm=p - bary,
                AP_abc_deg=apa,
                RP_abc_deg=rpa,
                dAP_p_mm=dap,
                dRP_l_mm=drp,
                drift_span_min=span,
            )
        )
        bars = []
        for a in approaches:
            s_a = (test.pose == pose) & (test.approach == a) & keep
            if s_a.sum() >= 1:
                bars.append(test.p_mm[s_a].mean(axis=0))
        if len(bars) >= 2:
            vap[pose] = ch.multidirectional_variation(np.array(bars))
    pair = _pair(test.poses, cfg.distance_pair)
    ad = rd = None
    if pair is not None:
        ad, rd = _distance(test, keep, ap_approach, pair)
        if ad is None:
            pair = None
    return IsoResult(results, vap, ad, rd, pair, left_out, {"ap_approach": ap_approach, "gross_error_rule": rule})


def _pair(poses: list[str], wanted: tuple[str, str]) -> tuple[str, str] | None:
    if wanted[0] in poses and wanted[1] in poses and wanted[0] != wanted[1]:
        return wanted
    return (poses[0], poses[1]) if len(poses) >= 2 else None


def _distance(
    test: IsoTest, keep: np.ndarray, approach: str, pair: tuple[str, str]
) -> tuple[float | None, float | None]:
    """AD_p, RD over the cycles in which both poses of the pair were attained (and kept)."""
    by: list[dict[int, int]] = []
    for label in pair:
        idx = np.flatnonzero((test.pose == label) & (test.approach == approach) & keep)
        by.append({int(test.cycle[i]): int(i) for i in idx})
    cycles = sorted(set(by[0]) & set(by[1]))
    if len(cycles) < 2:
        return None, None
    i1 = np.array([by[0][c] for c in cycles])
    i2 = np.array([by[1][c] for c in cycles])
    ad, rd, _, _ = ch.distance_characteristics(test.p_mm[i1], test.p_mm[i2], test.cmd_mm[i1[0]], test.cmd_mm[i2[0]])
    return ad, rd


__all__ = ["GROSS_RULE", "IsoResult", "IsoTest", "PoseResult", "evaluate"]
