"""The measurement noise the data imply, by three independent routes.

* **fit**: the tracker noise per coordinate the fit's residuals imply, ``sigma_cfg · sqrt(chi² / dof)``, with
  its 95 % interval from the chi² distribution (it holds *model misfit* as well as noise: an incomplete model
  inflates it);
* **rigid tool** (several targets on one tool, measured in the same pose): the distance between two targets
  is the same in every pose whatever the robot's kinematics, so its spread across poses is pure measurement
  noise: ``var(d) = 2 sigma²`` for isotropic per-coordinate noise ``sigma``;
* **repeated poses** (the same pose and target measured more than once within ``repeat_window_s``): the
  difference of two measurements has per-coordinate variance ``2 sigma²`` (repeatability of robot and tracker
  together, which is what the calibration can reach at best).

The routes that do not depend on the kinematic model let discovery judge "unexplained" against noise the
data show, not the configured value.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy import special


def fit_noise(chi2: float, dof: int, noise_mm: float, position_only: bool = True) -> dict[str, Any]:
    """Per-coordinate noise implied by a fit's chi² (computed with ``noise_mm``), with a 95 % interval."""
    red = chi2 / max(dof, 1)
    lo_q, hi_q = special.chdtri(max(dof, 1), 0.025), special.chdtri(max(dof, 1), 0.975)
    out: dict[str, Any] = {
        "sigma_mm": float(noise_mm * np.sqrt(red)),
        "ci95_mm": [float(noise_mm * np.sqrt(chi2 / lo_q)), float(noise_mm * np.sqrt(chi2 / hi_q))],
        "dof": int(dof),
        "source": "fit residuals (reduced chi-square x configured noise; includes any model misfit)",
    }
    if not position_only:
        out["source"] = str(out["source"]) + "; positions and orientations together, each scaled by its noise"
    return out


def _visits(pose_id: np.ndarray, station: np.ndarray | None) -> np.ndarray:
    """One label per row for a pose seen from one instrument placement: a pose measured from two tracker stations
    is two visits (each station's coordinates are its own frame: a difference across them is the stations' offset,
    not noise — a configuration measured from both stations read as a 1.6 m noise, and discovery fitted nothing)."""
    pid = np.asarray(pose_id).astype(str)
    if station is None:
        return pid
    return np.char.add(np.char.add(pid, "\x1f"), np.asarray(station).astype(str))


def rigid_tool_noise(
    pose_id: np.ndarray,
    target: np.ndarray,
    timestamp_s: np.ndarray,
    p_mm: np.ndarray,
    window_s: float = 120.0,
    station: np.ndarray | None = None,
) -> dict[str, Any] | None:
    """Noise from the inter-target distances of a rigid multi-target tool (None with fewer than 2 targets or
    fewer than 3 poses with two targets). Targets of one pose count together when measured within ``window_s``
    from one ``station`` (each row's instrument placement; None: one)."""
    names = sorted(set(map(str, target)))
    if len(names) < 2:
        return None
    groups: dict[str, list[int]] = {}
    for i, pid in enumerate(_visits(pose_id, station)):
        groups.setdefault(str(pid), []).append(i)
    by_pair: dict[tuple[str, str], list[float]] = {}
    for idx in groups.values():
        # one measurement of each target per pose visit: the rows close in time to the first
        seen: dict[str, int] = {}
        t0 = timestamp_s[idx[0]]
        for i in idx:
            if abs(timestamp_s[i] - t0) <= window_s and str(target[i]) not in seen:
                seen[str(target[i])] = i
        ts = sorted(seen)
        for a in range(len(ts)):
            for b in range(a + 1, len(ts)):
                d = float(np.linalg.norm(p_mm[seen[ts[a]]] - p_mm[seen[ts[b]]]))
                by_pair.setdefault((ts[a], ts[b]), []).append(d)
    ss = 0.0
    dof = 0
    for v in by_pair.values():
        if len(v) >= 2:
            arr = np.asarray(v)
            ss += float(np.sum((arr - arr.mean()) ** 2))
            dof += len(arr) - 1
    if dof < 2:
        return None
    sigma = float(np.sqrt(ss / dof / 2.0))
    lo_q, hi_q = special.chdtri(dof, 0.025), special.chdtri(dof, 0.975)
    return {
        "sigma_mm": sigma,
        "ci95_mm": [float(np.sqrt(ss / lo_q / 2.0)), float(np.sqrt(ss / hi_q / 2.0))],
        "dof": int(dof),
        "source": f"spread of inter-target distances on the rigid tool ({len(by_pair)} target pair(s))",
    }


def repeat_noise(
    pose_id: np.ndarray,
    target: np.ndarray,
    timestamp_s: np.ndarray,
    p_mm: np.ndarray,
    window_s: float = 600.0,
    station: np.ndarray | None = None,
) -> dict[str, Any] | None:
    """Noise from the same pose and target measured again within ``window_s`` from the same ``station`` (each
    row's instrument placement; None: one), None when there is no pair."""
    pid = _visits(pose_id, station)
    tg = np.asarray(target).astype(str)
    order = np.lexsort((timestamp_s, tg, pid))  # by pose, target, then time
    same = (pid[order][1:] == pid[order][:-1]) & (tg[order][1:] == tg[order][:-1])
    close = np.diff(np.asarray(timestamp_s, dtype=float)[order]) <= window_s
    pair = np.flatnonzero(same & close)
    if len(pair) < 2:
        return None
    D = p_mm[order][pair + 1] - p_mm[order][pair]
    dof = D.size
    ss = float(np.sum(D**2))
    lo_q, hi_q = special.chdtri(dof, 0.025), special.chdtri(dof, 0.975)
    return {
        "sigma_mm": float(np.sqrt(ss / dof / 2.0)),
        "ci95_mm": [float(np.sqrt(ss / lo_q / 2.0)), float(np.sqrt(ss / hi_q / 2.0))],
        "dof": int(dof),
        "source": f"{len(D)} pair(s) of repeated measurements of one pose and target within {window_s:g} s",
    }


def noise_report(
    campaign: Any,
    kept: np.ndarray | None,
    chi2_pos: float,
    dof: int,
    noise_mm: float,
) -> dict[str, Any]:
    """The ``fit.noise`` section: the configured value, what the data imply by each route, and the one to
    judge residuals against (the model-free routes when the data have them, else the configured value)."""
    c = campaign if kept is None else campaign.subset(kept)
    routes: dict[str, Any] = {"fit": fit_noise(chi2_pos, dof, noise_mm)}
    st = getattr(c, "station", None)
    rt = rigid_tool_noise(c.pose_id, c.target, c.timestamp_s, c.p_mm, station=st)
    if rt:
        routes["rigid_tool"] = rt
    rp = repeat_noise(c.pose_id, c.target, c.timestamp_s, c.p_mm, station=st)
    if rp:
        routes["repeated_poses"] = rp
    independent = [routes[k] for k in ("rigid_tool", "repeated_poses") if k in routes]
    if independent:
        best = max(independent, key=lambda r: r["dof"])
        use = max(noise_mm, best["sigma_mm"])
        why = (
            f"the larger of the configured {noise_mm:g} mm and the model-free estimate {best['sigma_mm']:.4g} mm "
            f"({best['source']})"
        )
    else:
        use = noise_mm
        why = "the configured value: the campaign has no model-free noise estimate (one target, no repeated poses)"
    return {"configured_mm": float(noise_mm), "routes": routes, "used_mm": float(use), "used_because": why}


#: the mean length of a 3-D error of independent normal coordinates of unit standard deviation (2 sqrt(2 / pi))
MEAN_NORM_3D = 2.0 * np.sqrt(2.0 / np.pi)


def noise_hint(summ: Mapping[str, Any]) -> str:
    """When "unexplained" rests on the configured noise alone (no model-free estimate in the campaign) and the
    held-out error is what a larger noise alone would give: that noise, and that the floor may be the instrument's
    (a newcomer's laser tracker of 0.02 mm was told "unexplained" at a held-out error on its floor); else ""."""
    nz, cv = summ.get("noise") or {}, summ.get("cross_validation") or {}
    if "model-free" not in str(nz.get("used_because") or "") or "larger of" in str(nz.get("used_because") or ""):
        return ""
    cv_mean = cv.get("cv_mean_position_mm")
    used = nz.get("used_mm")
    if cv_mean is None or used is None or summ.get("uses_orientation"):
        return ""
    implied = float(cv_mean) / MEAN_NORM_3D
    if implied <= 1.1 * float(used):
        return ""
    return (
        f"the floor is the configured noise ({float(used):.4f} mm per coordinate), which this campaign cannot check "
        f"(one target, no repeated poses): its held-out error (mean {float(cv_mean):.4f} mm) is what noise of "
        f"{implied:.4f} mm alone would give; if the instrument's noise is that, set noise_mm={implied:.3f}"
    )
