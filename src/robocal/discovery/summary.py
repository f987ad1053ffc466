"""From a :class:`DiscoveryResult` to ``discovery.json``: named effects with estimates, steps, and where an
unexplained residual lives (joints, workspace region, time span)."""

from __future__ import annotations

from typing import Any

import numpy as np

from robocal.discovery.ftest import basis
from robocal.discovery.model import Accepted, Fit, tracker_columns
from robocal.discovery.scoring import Step
from robocal.discovery.search import DiscoveryResult
from robocal.discovery.session_cv import MEASUREMENT_FAMILIES
from robocal.kinematics.chain import fk
from robocal.logged_signals import ANGLE_UNITS
from robocal.metrics import ErrorStats

_DEG = float(np.rad2deg(1.0))


def _est(value: float, se: float, unit: str) -> dict[str, Any]:
    return {"value": float(value), "stderr": None if not np.isfinite(se) else float(se), "unit": unit}


def edge_order(est: dict[str, Any]) -> str:
    """A transmission error whose largest harmonic is the highest order fitted: what its amplitudes cannot say
    (a newcomer's 37 cycles per revolution, planted, read as harmonic 36 at 2.7 times the amplitude ± 17 %); ""
    otherwise."""
    amps = {int(k.split("_")[1]): v["value"] for k, v in est.items() if k.startswith("harmonic_")}
    K = int(est["order"]["value"])
    if not amps or max(amps, key=lambda h: amps[h]) != K:
        return ""
    return (
        f"the largest harmonic is the highest order fitted ({K}): the error may be of a higher order than the poses "
        f"resolve (order K needs 8 K poses), its energy spread over the fitted harmonics; the amplitudes and their "
        "standard errors are of the fitted series under its prior, not of a resolved harmonic"
    )


def estimates(fit: Fit, acc: Accepted) -> dict[str, Any]:
    """Estimates with standard errors of one accepted effect, in readable units."""
    c = acc.cand
    model = fit.model
    names = list(acc.coef_names)
    val = np.array([fit.theta[model.index(n)] for n in names]) if names else np.zeros(0)
    C = fit.cov_of(names) if names else np.zeros((0, 0))
    se = np.sqrt(np.diag(C)) if names else np.zeros(0)
    out: dict[str, Any] = {}
    if c.effect == "gear":
        s, co = val
        out["sin_deg"] = _est(s * _DEG, se[0] * _DEG, "deg")
        out["cos_deg"] = _est(co * _DEG, se[1] * _DEG, "deg")
        amp = float(np.hypot(s, co))
        g = np.array([s, co]) / amp if amp > 0 else np.zeros(2)
        out["amplitude_deg"] = _est(amp * _DEG, float(np.sqrt(g @ C @ g)) * _DEG, "deg")
        # dq = A sin(h q + phi) = A cos(phi) sin(h q) + A sin(phi) cos(h q)
        gp = np.array([-co, s]) / amp**2 if amp > 0 else np.zeros(2)
        out["phase_deg"] = _est(np.rad2deg(np.arctan2(co, s)), float(np.sqrt(gp @ C @ gp)) * _DEG, "deg")
    elif c.effect == "transmission":
        h = np.asarray(c.extra["harmonics"], dtype=int)
        H = len(h)
        amps = np.hypot(val[:H], val[H:])
        for k in np.argsort(-amps)[:3]:
            g = np.zeros(2 * H)
            if amps[k] > 0:
                g[k], g[H + k] = val[k] / amps[k], val[H + k] / amps[k]
            se_k = float(np.sqrt(g @ C @ g)) * _DEG
            out[f"harmonic_{int(h[k])}_amplitude_deg"] = _est(float(amps[k]) * _DEG, se_k, "deg")
        out["order"] = {"value": int(h.max()), "stderr": None, "unit": "harmonics per revolution"}
        out.update(_deflection(fit, acc, val, C))
    elif c.effect == "weight":
        out.update(_deflection(fit, acc, val, C))
    elif c.effect == "backlash":
        out["band_deg"] = _est(2 * val[0] * _DEG, 2 * se[0] * _DEG, "deg")
    elif c.effect == "compliance":
        unit = c.coef_units[0]
        key = "c_rad_per_A" if unit == "rad/A" else "c_rad_per_Nm"
        out[key] = _est(val[0], se[0], unit)
    elif c.effect == "scale":
        for k, (n, u) in enumerate(zip(c.coef_names, c.coef_units, strict=True)):
            out[n] = _est(val[k], se[k], u)
    elif c.effect == "axis":  # a linear axis's carriage error: mm, or urad (per kN·m for the bending)
        for k, (n, u) in enumerate(zip(c.coef_names, c.coef_units, strict=True)):
            f, unit = (1.0, "mm") if u == "mm" else (1e6, "urad" if u == "rad" else "urad/kNm")
            out[n] = _est(val[k] * f, se[k] * f, unit)
    elif c.effect == "beta":
        nm = f"beta{c.joint}"
        out[f"{nm}_deg"] = _est(fit.theta[model.index(nm)] * _DEG, fit.stderr(nm) * _DEG, "deg")
    elif c.effect in ("thermal", "drift", "air", "regap", "misfit"):
        out.update(_drift_estimates(fit, acc, val, se))
    elif c.effect in ("signal", "session"):
        out.update(_signal_estimates(acc, val, se))
    return out


def _signal_estimates(acc: Accepted, val: np.ndarray, se: np.ndarray) -> dict[str, Any]:
    """Estimates of an effect driven by a logged signal: per coefficient in deg (rotations) or mm per unit of
    the signal, and for a rotation driven by a signal declared as an angle its dimensionless gain."""
    c = acc.cand
    col = c.extra["column"]
    unit = (c.extra.get("signal_info") or {}).get("unit") or "unit"
    per_rad = ANGLE_UNITS.get(unit)
    out: dict[str, Any] = {}
    if c.effect == "session":  # the session's tool re-seated: its move on the flange against the first session's
        return {f"tool_{n}_mm": _est(val[k], se[k], "mm") for k, n in enumerate(c.coef_names)}
    if c.shape == "tracker":  # the tracker's scale, ppm per unit of the signal
        return {f"ppm_per_{col}": _est(val[0], se[0], f"ppm/{unit}")}
    for k, n in enumerate(c.coef_names):
        rotation = c.coef_units[k].startswith("rad")
        f = _DEG if rotation else 1.0
        u = "deg" if rotation else "mm"
        label = f"{n}_{u}_per_{col}" if n != "c" else f"dq{c.joint}_{u}_per_{col}"
        out[label] = _est(val[k] * f, se[k] * f, f"{'deg' if rotation else 'mm'}/{unit}")
        if rotation and per_rad is not None:
            out[f"{n}_gain" if n != "c" else "gain"] = _est(val[k] / per_rad, se[k] / per_rad,
                                                              f"rad per rad of {col}")  # fmt: skip
    return out


_AXIS_WORDS = {"rx": "about x", "ry": "about y", "rz": "about z", "tx": "along x", "ty": "along y",
               "tz": "along z", "c": ""}  # fmt: skip


def signal_statement(acc: Accepted, est: dict[str, Any]) -> str:
    """One sentence for an effect driven by a logged signal (``the base tilts 1.002 × incl_x about x (± 0.004)``):
    the coefficients more than three standard errors from zero (else the largest), as gains when the signal is an
    angle."""
    c = acc.cand
    col = c.extra["column"]
    frame = c.extra.get("frame")
    if c.shape == "tracker":
        e = est[f"ppm_per_{col}"]
        return f"the tracker's scale changes by {e['value']:.4g} ppm per {e['unit'].split('/', 1)[1]} of {col} " + (
            f"(± {float(e['stderr']):.2g})" if e["stderr"] is not None else ""
        )
    turns = "slides" if c.coef_units and c.coef_units[0].startswith("mm") else "turns"  # a linear axis: mm
    subject = {"base_rot": "the base tilts", "base_trans": "the base moves", "tool_rot": "the tool tilts",
               "tool_trans": "the tool moves", "carriage_rot": "the carriage tilts",
               None: f"joint {c.joint} {turns}"}[frame]  # fmt: skip
    parts = []
    for n in c.coef_names:
        gain = est.get(f"{n}_gain" if n != "c" else "gain")
        key = next(k for k in est if k.startswith((f"{n}_deg_per_", f"{n}_mm_per_", f"dq{c.joint}_")))
        e = gain if gain is not None else est[key]
        v, s = float(e["value"]), e["stderr"]
        sig = s is None or abs(v) > 3.0 * float(s)
        if gain is not None:
            txt = f"{v:.4g} × {col}"
        else:
            txt = f"{v:.4g} {e['unit'].split('/')[0]} per {e['unit'].split('/', 1)[1]} of {col}"
        txt += (f" {_AXIS_WORDS[n]}" if _AXIS_WORDS[n] else "") + (f" (± {float(s):.2g})" if s is not None else "")
        parts.append((sig, abs(v) / (float(s) if s else 1.0), txt))
    shown = [t for sig, _, t in parts if sig] or [max(parts)[2]]
    return f"{subject} " + ", ".join(shown)


def _drift_estimates(fit: Fit, acc: Accepted, val: np.ndarray, se: np.ndarray) -> dict[str, Any]:
    """Estimates of a parameter drift (thermal, drift, air, regap): per parameter and signal, and for the
    tracker's drift its velocity in the tracker frame."""
    c = acc.cand
    model = fit.model
    names = list(acc.coef_names)
    out: dict[str, Any] = {}
    for k, n in enumerate(names):
        p = n.split(":", 1)[1]
        pname, sig = p.split("*")
        unit_p = model.base.units[model.base.index(pname)]
        f = _DEG if unit_p == "rad" else 1.0
        unit = "deg" if unit_p == "rad" else "mm"
        if sig.startswith(("after_gap", "after_step")) or sig == "in_condition":  # a step: the frame's change
            out[f"{pname}_{sig}"] = _est(val[k] * f, se[k] * f, unit)
            continue
        per = "h" if sig == "t_h" else f"°C ({sig})"
        out[f"{pname}_per_{sig}"] = _est(val[k] * f, se[k] * f, f"{unit}/{per}")
    if c.effect == "drift":
        R = model.base.T_ref[:3, :3]
        tn = [f"drift:base_t{a}*t_h" for a in "xyz"]
        if all(n in names for n in tn):
            v = np.array([fit.theta[model.index(n)] for n in tn])
            Ct = fit.cov_of(tn)
            Ct = np.where(np.isfinite(Ct), Ct, 0.0)
            vt = R @ v
            st = np.sqrt(np.diag(R @ Ct @ R.T))
            for a, axis in enumerate("xyz"):
                out[f"tracker_{axis}_mm_per_h"] = _est(vt[a], st[a], "mm/h")
    return out


def _deflection(fit: Fit, acc: Accepted, val: np.ndarray, C: np.ndarray) -> dict[str, Any]:
    """RMS and largest joint deflection of a many-coefficient joint effect over the fitted poses, with standard
    errors (the RMS's by the delta method), and whether it is physical (``weight``: at most three times the
    prior's RMS)."""
    S = acc.cand.S[_rows(fit)]
    dq = S @ val
    rms = float(np.sqrt(np.mean(dq**2)))
    g = (S.T @ dq) / (len(dq) * rms) if rms > 0 else np.zeros(len(val))
    Cf = np.where(np.isfinite(C), C, 0.0)
    k = int(np.argmax(np.abs(dq)))
    out = {
        "rms_deflection_deg": _est(rms * _DEG, float(np.sqrt(max(g @ Cf @ g, 0.0))) * _DEG, "deg"),
        "max_deflection_deg": _est(float(dq[k]) * _DEG, float(np.sqrt(max(S[k] @ Cf @ S[k], 0.0))) * _DEG, "deg"),
    }
    prior = acc.cand.extra.get("prior_deg")
    if prior is not None:
        out["physical"] = {"value": bool(rms * _DEG <= 3.0 * float(prior)), "stderr": None,
                           "unit": f"RMS deflection within 3x the prior ({prior} deg)"}  # fmt: skip
    return out


def effect_displacement(fit: Fit, acc: Accepted) -> np.ndarray:
    """The modelled displacement ``(m, 3)`` mm of each fitted row due to one accepted effect (first order)."""
    model = fit.model
    m = fit.Jx.shape[0]
    c = acc.cand
    if c.shape == "structure":
        return np.zeros((m, 3))
    sl = model.slices[model.accepted.index(acc)]
    th = fit.theta[sl]
    if c.shape == "joint":
        assert c.joint is not None
        return fit.Jq[:, :3, c.joint - 1] * (c.S[_rows(fit)] @ th)[:, None]
    if c.shape == "tracker":
        return np.einsum("mij,j->mi", tracker_columns(c, _rows(fit)), th)
    if c.shape == "axis":
        from robocal.discovery.axes import axis_rows
        from robocal.identification.model import FitData

        names = model.base.target_names
        camp_rows = _rows(fit)
        ti = np.array([names.index(t) if t in names else 0 for t in np.asarray(c.extra["target"])[camp_rows]])
        d = FitData(c.extra["q"][camp_rows], np.zeros((m, 3)), ti)
        d = d.with_q(d.q + model.joint_offsets(fit.theta, camp_rows, 0))
        return np.einsum("mij,j->mi", axis_rows(c, model.base, fit.theta[: model.nb], d, camp_rows, 3), th)
    if c.shape == "frame":
        from robocal.discovery.logged import frame_rows

        names = model.base.target_names
        ti = np.array([names.index(t) if t in names else 0 for t in np.asarray(c.extra["target"])[_rows(fit)]])
        cols = frame_rows(c, fit.Jx, model.base, fit.theta[: model.nb], ti, _rows(fit))
        return np.einsum("mij,j->mi", cols[:, :3, :], th)
    idx = [model.base.index(p) for p in acc.params]
    cols = fit.Jx[:, :3, idx][:, :, :, None] * c.S[_rows(fit)][:, None, None, :]
    return np.einsum("mij,j->mi", cols.reshape(m, 3, -1), th)


#: Measurements more than this apart start a new measurement state (a warm-up measures its pose set in bursts).
STATE_GAP_S = 600.0


def state_drift(res: DiscoveryResult, acc: Accepted) -> dict[str, Any]:
    """The modelled drift of the measured points per measurement state, with standard errors.

    A parameter-drift effect (thermal, drift) moves every row by ``D_r = G_r theta`` (first order). Its constant
    part is absorbed by the geometry, so what is meaningful (and comparable with a truth) is the change since
    the *first* measurement of the same pose and target: ``D_r - D_ref(r)``, averaged over the rows of each
    state (states are bursts of measurements separated by more than :data:`STATE_GAP_S`). Standard errors from
    the coefficients' covariance: ``sqrt(diag(Gbar C Gbar^T))``, ``Gbar`` the state mean of ``G_r - G_ref(r)``.
    Returns ``{"states": [{"t_min", "n_rows", "x_mm", "y_mm", "z_mm"} ...]}`` (each axis value + stderr,
    tracker frame) and the arrays used (``state``, ``ref``) under private keys for tests.
    """
    fit = res.final
    c = acc.cand
    if c.shape != "param":
        return {}
    rows = _rows(fit)
    camp = res.campaign.subset(rows)
    model = fit.model
    sl = model.slices[model.accepted.index(acc)]
    idx = [model.base.index(p) for p in acc.params]
    m = len(rows)
    G = (fit.Jx[:, :3, idx][:, :, :, None] * c.S[rows][:, None, None, :]).reshape(m, 3, -1)
    names = list(acc.coef_names)
    C = fit.cov_of(names)
    C = np.where(np.isfinite(C), C, 0.0)  # fixed (unidentifiable) coefficients carry no variance
    D = np.einsum("mij,j->mi", G, fit.theta[sl])
    t = camp.timestamp_s
    first: dict[tuple[str, str], int] = {}
    for i in np.argsort(t, kind="stable"):
        first.setdefault((str(camp.pose_id[i]), str(camp.target[i])), int(i))
    ref = np.array([first[(str(camp.pose_id[i]), str(camp.target[i]))] for i in range(m)])
    ts = np.sort(t)
    cuts = ts[1:][np.diff(ts) > STATE_GAP_S]
    state = np.searchsorted(cuts, t, side="right")
    out = []
    for k in range(int(state.max()) + 1):
        sel = np.flatnonzero(state == k)
        d = (D[sel] - D[ref[sel]]).mean(axis=0)
        Gd = (G[sel] - G[ref[sel]]).mean(axis=0)
        se = np.sqrt(np.maximum(np.diag(Gd @ C @ Gd.T), 0.0))
        entry: dict[str, Any] = {"t_min": float((t[sel].min() - t.min()) / 60.0), "n_rows": len(sel)}
        for a, axis in enumerate("xyz"):
            entry[f"{axis}_mm"] = _est(d[a], se[a], "mm")
        out.append(entry)
    return {"states": out, "_state": state, "_ref": ref}


def _rows(fit: Fit) -> np.ndarray:
    assert fit.rows is not None, "Fit.rows must be set by the discovery run"
    return fit.rows


def locate(res: DiscoveryResult) -> dict[str, Any]:
    """Where the leftover lives: joints (a flexible joint-angle error per joint), workspace region, time span."""
    fit = res.final
    camp = res.campaign.subset(res.rows)
    dd = fit.d
    r = fit.r_w.reshape(-1, dd)
    m = r.shape[0]
    per_row = np.sum(r**2, axis=1)
    expect = dd * fit.dof / fit.M
    excess = float(fit.rss - fit.dof)
    out: dict[str, Any] = {"excess_chi2": excess, "chi2": fit.rss, "dof": fit.dof}
    # joints: share of the excess a generic joint-angle error (smooth in every joint angle) would explain
    q = camp.q
    n = q.shape[1]
    B = np.column_stack([np.ones(m)] + [f(h * q[:, k]) for k in range(n) for h in (1, 2) for f in (np.sin, np.cos)])
    fit.gram = None  # the joint-level factors: not needed beyond here, not held beside the SVD
    Q = F.space() if (F := fit.factors()) is not None else basis(fit)
    joints = []
    for j in range(n):
        # one joint's columns at a time, projected off the model in place: all of them at once, with the
        # products' temporaries, were the largest allocation of a 12 000-row discovery after its search (60 MB)
        Z = (fit.Jq[:, :, j][:, :, None] * B[:, None, :]).reshape(dd * m, -1)
        Z *= fit.weights[:, None]
        Q.remove(Z)
        U, s, _ = np.linalg.svd(Z, full_matrices=False)
        Uk = U[:, s > 1e-6 * (s[0] if len(s) else 1.0)]
        d = float(np.sum((Uk.T @ fit.r_w) ** 2))
        dfree = Uk.shape[1]
        joints.append(
            {"joint": j + 1, "explained_share_of_excess": (d - dfree) / excess if excess > 0 else 0.0, "dof": dfree}
        )
    del Q
    joints.sort(key=lambda t: -t["explained_share_of_excess"])
    out["joints"] = joints
    # workspace: octants of the flange position (base frame): reach, height and side split at their medians
    T = fk(fit.model.base.chain, q)
    pos = T[:, :3, 3]
    reach = np.hypot(pos[:, 0], pos[:, 1])
    side = np.arctan2(pos[:, 1], pos[:, 0])
    cells: dict[tuple[int, int, int], list[int]] = {}
    mid = (np.median(reach), np.median(pos[:, 2]), np.median(side))  # once, not per row (0.8 s at 8 000 rows)
    for i in range(m):
        key = (int(reach[i] > mid[0]), int(pos[i, 2] > mid[1]), int(side[i] > mid[2]))
        cells.setdefault(key, []).append(i)
    regions = []
    for key, idx in cells.items():
        ii = np.array(idx)
        regions.append(
            {
                "reach": "far" if key[0] else "near",
                "height": "high" if key[1] else "low",
                "side": "left" if key[2] else "right",
                "n_rows": len(ii),
                "reach_mm": [float(reach[ii].min()), float(reach[ii].max())],
                "z_mm": [float(pos[ii, 2].min()), float(pos[ii, 2].max())],
                "mean_chi2_per_row_over_expected": float(per_row[ii].mean() / expect),
            }
        )
    regions.sort(key=lambda t: -float(t["mean_chi2_per_row_over_expected"]))  # type: ignore[arg-type]
    out["workspace_regions"] = regions
    # time: the contiguous span (in time order) holding the largest excess
    order = np.argsort(camp.timestamp_s, kind="stable")
    e = per_row[order] - expect
    best, cur, start, b0, b1 = -np.inf, 0.0, 0, 0, 0
    for i, v in enumerate(e):
        if cur <= 0:
            cur, start = v, i
        else:
            cur += v
        if cur > best:
            best, b0, b1 = cur, start, i
    t = camp.timestamp_s[order]
    out["time_span"] = {
        "t_start_s": float(t[b0]),
        "t_end_s": float(t[b1]),
        "n_rows": int(b1 - b0 + 1),
        "share_of_excess": float(best / excess) if excess > 0 else 0.0,
    }
    return out


def _step_dict(k: int, st: Step, res: DiscoveryResult) -> dict[str, Any]:
    cand = next((c for c in res.library if c.key == st.accepted), None)
    from robocal.discovery.scoring import PHASES

    return {
        "step": k,
        "phase": PHASES.get(st.phase, st.phase),
        "label": st.label or _stop_text(st),
        "accepted": st.accepted,
        "effect": None if cand is None else cand.effect,
        "joint": None if cand is None else cand.joint,
        "harmonic": None if cand is None else cand.harmonic,
        "rms_before_mm": st.rms_before_mm,
        "rms_after_mm": st.rms_after_mm,
        "chi2_before": st.chi2_before,
        "chi2_after": st.chi2_after,
        "dof_after": st.dof_after,
        "dropped": st.dropped,
        "candidates": [s.to_dict() for s in sorted(st.scores, key=_score_key)],
    }


def _stop_text(st: Step) -> str:
    """What a step that accepted nothing says: which phase stopped, and why."""
    if st.phase == "library":
        return "library F-test search stopped: no candidate passes the F-test, the BIC and the excess share"
    return "stopped"


def _score_key(s: Any) -> float:
    return float(s.log10_p) if np.isfinite(s.log10_p) else 1.0


def summary(res: DiscoveryResult, validation: dict[str, Any] | None = None) -> dict[str, Any]:
    """The ``discovery.json`` content."""
    fit = res.final
    named = []
    proposed = []
    for acc in res.accepted:
        c = acc.cand
        if c.effect == "proposed":
            proposed.append(proposal_dict(res, acc))
            continue
        step = next((st for st in res.steps if st.accepted == c.key), None)
        sc = next((s for s in step.scores if s.key == c.key), None) if step else None
        named.append(
            {
                "effect": c.effect,
                "joint": c.joint,
                "harmonic": c.harmonic,
                "estimates": estimates(fit, acc),
                "key": c.key,
                "cause": c.cause,
                "signal": c.signal,
                "selection": None if sc is None else sc.to_dict(),
                "rms_of_effect_mm": ErrorStats.of(effect_displacement(fit, acc)).rms_mm,
                "side": "measurement" if c.effect in MEASUREMENT_FAMILIES else c.extra.get("side", "robot"),
                "held_out": (res.extra.get("cv") or {}).get("effects", {}).get(c.key),
            }
        )
        if c.effect == "transmission" and edge_order(named[-1]["estimates"]):
            named[-1]["caveat"] = edge_order(named[-1]["estimates"])
        if c.effect == "signal":
            named[-1]["statement"] = signal_statement(acc, named[-1]["estimates"])
            named[-1]["logged_signal"] = c.extra["signal_info"]
        if c.effect in ("thermal", "drift", "air", "regap"):
            # the effect at the tool, per measurement state, relative to each pose's first measurement: the
            # quantity with a physical meaning (and a truth on the twin), unlike the per-component coefficients
            est = named[-1]["estimates"]
            assert isinstance(est, dict)
            est["drift_by_state"] = state_drift(res, acc).get("states", [])
    out: dict[str, Any] = {
        "robot": res.robot.name,
        "named": named,
        "proposed": proposed,
        "steps": [_step_dict(k + 1, st, res) for k, st in enumerate(res.steps)],
        "rms_before_mm": res.geometric.rms_mm,
        "rms_after_mm": fit.rms_mm,
        "noise_floor_mm": fit.noise_floor_mm,
        "noise_mm": float(res.extra.get("sigma_mm", res.config.noise_mm)),
        "noise": res.extra.get("noise"),
        "outliers": res.extra.get("outliers", []),
        "outlier_rule": res.extra.get("outlier_rule"),
        "left_out_poorly_predicted": res.extra.get("left_out_poorly_predicted", []),
        **{k: res.extra[k] for k in ("left_out_systematic", "left_out_earlier") if res.extra.get(k)},
        # rows that misfit together under one condition against the final model (robocal.identification.misfit)
        "systematic_misfit": res.extra.get("systematic_misfit", []),
        "n_rows_total": len(res.rows)
        + len(res.extra.get("outliers", []))
        + len(res.extra.get("left_out_poorly_predicted", []))
        + len(res.extra.get("left_out_systematic", []))
        + len(res.extra.get("left_out_earlier", [])),
        "uses_orientation": bool(res.extra.get("uses_orientation", False)),
        "chi2": fit.rss,
        "dof": fit.dof,
        "chi2_p_value": res.chi2_p_value,
        "unexplained": res.unexplained,
        "skipped": [s.to_dict() for s in res.skipped],
        "unidentifiable": [
            {"key": k, "absorbed_share": v, "reason": "the current model absorbs its regressor completely"}
            for k, v in res.unidentifiable.items()
        ],
        "library": [
            {
                "key": c.key,
                "effect": c.effect,
                "joint": c.joint,
                "harmonic": c.harmonic,
                "cause": c.cause,
                "signal": c.signal,
            }
            for c in res.library
        ],
        "selection": {
            "n_tests": res.n_tests,
            "family_wise_alpha": res.config.alpha,
            "threshold_log10_p": res.threshold_log10_p,
            "min_excess_share": res.config.min_excess_share,
            "cv_folds": res.config.cv_folds,
            **(
                {
                    "signal_tests": res.extra["signal_tests"],
                    "signal_threshold_log10_p": res.extra["signal_threshold_log10_p"],
                }
                if res.extra.get("signal_tests")
                else {}
            ),
        },
        "n_rows": len(res.rows),
        "wall_time_s": res.wall_time_s,
        "config": res.config.to_dict(),
    }
    # the records only some runs have: the logged signals; grow_geometry auto and several transmission windows
    # (which search was kept, and each one's CV figure); a large campaign's first search on a sample (issue 31);
    # the part's rows (robocal calibrate's positioner fit)
    for key in ("logged_signals", "grow_geometry", "geometry_prior", "counterbalance", "transmission_window",
                "gross_error_screen", "positioner_part_rows_left_out"):  # fmt: skip
        if res.extra.get(key) is not None:
            out[key] = res.extra[key]
    if res.unexplained:
        out["unexplained_where"] = locate(res)
    geo = res.extra.get("geometric_calibration")
    if geo is not None:
        # robocal calibrate's own figures on the same campaign (its rows, noise and gross errors), to read the
        # discovery against: the search's first step refits that geometry with the discovery's weights
        out["geometric_calibration"] = {
            "rms_position_mm": geo.fit.get("rms_position_mm"),
            "noise_floor_rms_mm": geo.fit.get("noise_floor_rms_mm"),
            "noise_used_mm": (geo.fit.get("noise") or {}).get("used_mm"),
            "noise_used_because": (geo.fit.get("noise") or {}).get("used_because"),
            "n_rows": int(np.sum(geo.start.kept)) if geo.start is not None else None,
            # tracker placements (the key only with several: a one-station campaign's discovery.json unchanged)
            **({"n_stations": len(geo.fit["stations"])} if len(geo.fit.get("stations") or []) > 1 else {}),
            "outlier_rows": [o["row"] for o in geo.fit.get("outliers", [])],
            "systematic_misfit": geo.fit.get("systematic_misfit", []),
        }
        if geo.fit.get("orientation_left_out"):  # the campaign's orientations are not the robot's: positions only
            out["warnings"] = [str(geo.fit["orientation_left_out"])]
    cv = res.extra.get("cv") or {}
    if cv:
        out["cross_validation"] = {k: v for k, v in cv.items() if k != "effects"}
    if validation is not None:
        out["validation"] = validation
    from robocal.discovery.validate import negative_compliance, unknown_units, worse_than_geometry

    # a result worse than its start is said, a stiffness that cannot be, and a unit that is an angle's near miss
    said = worse_than_geometry(validation, cv) + negative_compliance(out.get("named", []))
    if said := said + unknown_units(out.get("logged_signals")):
        out.setdefault("warnings", []).extend(said)
    return out


def proposal_dict(res: DiscoveryResult, acc: Accepted) -> dict[str, Any]:
    """A proposed equation (dictionary stage) with its estimates, standard errors and selection evidence."""
    fit = res.final
    c = acc.cand
    names = list(acc.coef_names)
    val = np.array([fit.theta[fit.model.index(n)] for n in names])
    C = fit.cov_of(names)
    se = np.sqrt(np.where(np.isfinite(np.diag(C)), np.diag(C), np.nan))
    terms = []
    parts = []
    for k, t in enumerate(c.extra["terms"]):
        v, e = float(val[k] * _DEG), float(se[k] * _DEG)
        terms.append({**t, "coefficient_deg": _est(v, e, "deg")})
        sign = "-" if v < 0 else ("+" if k else "")
        parts.append(f"{sign} {abs(v):.4f}° ± {e:.4f}° · {t['signal']}".strip())
    step = next((st for st in res.steps if st.accepted == c.key), None)
    sc = next((x for x in step.scores if x.key == c.key), None) if step else None
    sel = {} if sc is None else sc.to_dict()
    sel.update(
        threshold_log10_p=c.extra.get("threshold_log10_p"),
        dictionary_columns=c.extra.get("n_columns"),
        stability=c.extra.get("stability"),
    )
    from robocal.discovery.dictionary import Term

    applicable = all(Term(tuple((f["kind"], f["index"], f["harmonic"]) for f in t["factors"])).from_joints_only
                     for t in c.extra["terms"])  # fmt: skip
    return {
        "joint": c.joint,
        "key": c.key,
        "equation": f"dθ{c.joint} = " + " ".join(parts),
        "terms": terms,
        "reading": c.cause,
        "selection": sel,
        "rms_of_effect_mm": ErrorStats.of(effect_displacement(fit, acc)).rms_mm,
        "compensated_online": applicable,
    }
