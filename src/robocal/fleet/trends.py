"""Did a parameter move more than its uncertainty allows? Tests across recalibrations of each robot.

For every robot, every kinematic parameter identified in its accepted calibrations (value ``v_k``, standard
error ``s_k`` at campaign ``k``, in date order):

* **step test**, each pair of consecutive campaigns: ``z = (v_{k+1} - v_k) / sqrt(s_k² + s_{k+1}²)``;
* **trend test**, robots with three or more campaigns: the weighted least-squares slope of ``v`` against time
  (weights ``1/s²``) over its standard error, ``z = b / se(b)``.

Both are two-sided normal tests; the threshold comes from a Bonferroni correction over *every* test of the fleet
(parameters × robots × (steps + trend)) at the family-wise false-flag rate ``alpha``:
``|z| > Φ⁻¹(1 - alpha / (2 m))``. With calibrated standard errors a fleet without any event raises a flag with
probability at most ``alpha``.

A flagged parameter is then described:

* with three or more campaigns, two patterns are fitted by weighted least squares, each with two parameters: a
  straight line in time (a steady drift) and two levels with one change point (a jump; the best change point);
  the one with the smaller χ² names the flag, ``drift`` or ``jump``, unless even that one leaves a lack-of-fit χ²
  with p < ``pattern_alpha`` (0.001: neither pattern explains the values): then ``change``. A drift e.g. is wear or a
  creeping link; a jump a zero offset after a motor or encoder change, a crash, a remounted part;
* with two campaigns a significant step is called a ``jump`` (two campaigns cannot tell a jump from a drift).

Base (tracker) and tool parameters are not tested: the tracker stands elsewhere at each campaign and the
reflector may be remounted.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from datetime import date
from typing import Any

import numpy as np
from scipy import stats

from robocal.errors import ConfigError


def _series(summaries: Sequence[Mapping[str, Any]], kinds: Sequence[str]) -> tuple[list[str], dict[str, Any]]:
    """Accepted campaigns' dates and {parameter: (values, stderrs, unit)} over parameters identified in all."""
    acc = [s for s in summaries if s.get("accepted")]
    dates = [str(s["date"]) for s in acc]
    out: dict[str, Any] = {}
    if not acc:
        return dates, out
    for p in acc[0]["parameters"]:
        if p.get("kind") not in kinds:
            continue
        name = p["name"]
        vals, ses = [], []
        for s in acc:
            q = next((x for x in s["parameters"] if x["name"] == name), None)
            if q is None or q.get("status") != "identified" or q.get("stderr") is None:
                break
            vals.append(float(q["value"]))
            ses.append(float(q["stderr"]))
        else:
            out[name] = (np.array(vals), np.array(ses), p.get("unit", ""))
    return dates, out


def _years(dates: Sequence[str]) -> np.ndarray:
    d0 = date.fromisoformat(dates[0][:10])
    return np.array([(date.fromisoformat(d[:10]) - d0).days / 365.25 for d in dates])


def _line(t: np.ndarray, v: np.ndarray, s: np.ndarray) -> tuple[float, float, float]:
    """Weighted LS line: (slope, its standard error, lack-of-fit chi²) with weights 1/s²."""
    w = 1.0 / s**2
    A = np.column_stack([np.ones_like(t), t])
    N = A.T @ (A * w[:, None])
    cov = np.linalg.inv(N)
    coef = cov @ (A.T @ (w * v))
    r = v - A @ coef
    return float(coef[1]), float(np.sqrt(cov[1, 1])), float(np.sum(w * r**2))


def _step_chi2(v: np.ndarray, s: np.ndarray) -> float:
    """Smallest χ² of a two-level model (one change point, anywhere) with weights 1/s²."""
    w = 1.0 / s**2
    best = np.inf
    for k in range(1, len(v)):
        chi2 = 0.0
        for part in (slice(0, k), slice(k, None)):
            m = np.sum(w[part] * v[part]) / np.sum(w[part])
            chi2 += float(np.sum(w[part] * (v[part] - m) ** 2))
        best = min(best, chi2)
    return best


def analyse(
    summaries: Mapping[str, Sequence[Mapping[str, Any]]],
    alpha: float = 0.01,
    kinds: Sequence[str] = ("kinematic",),
    pattern_alpha: float = 0.001,
) -> dict[str, Any]:
    """Run the tests over a fleet. ``summaries`` maps serial -> campaign summaries in date order
    (:mod:`robocal.fleet.engine`). Returns the test settings, the flags and each robot's series."""
    if not 0 < alpha < 1:
        raise ConfigError(f"The 'drift.alpha' fleet setting must be in (0, 1). Got {alpha!r} instead.")
    robots: dict[str, Any] = {}
    tests: list[tuple[str, str, str, int, float]] = []  # serial, parameter, test, step index, z
    for serial, summ in summaries.items():
        dates, series = _series(summ, kinds)
        robots[serial] = {"dates": dates, "parameters": {}}
        if len(dates) < 2:
            continue
        t = _years(dates)
        for name, (v, s, unit) in series.items():
            dz = np.diff(v) / np.sqrt(s[:-1] ** 2 + s[1:] ** 2)
            entry: dict[str, Any] = {"unit": unit, "value": v.tolist(), "stderr": s.tolist(), "step_z": dz.tolist()}
            for k, z in enumerate(dz):
                tests.append((serial, name, "step", k, float(z)))
            if len(v) >= 3 and t[-1] > t[0]:
                b, sb, chi2 = _line(t, v, s)
                entry.update(
                    {
                        "slope_per_year": b,
                        "slope_stderr": sb,
                        "trend_z": b / sb,
                        "line_chi2": chi2,
                        "step_chi2": _step_chi2(v, s),
                    }
                )
                tests.append((serial, name, "trend", -1, b / sb))
            robots[serial]["parameters"][name] = entry
    m = len(tests)
    z_crit = float(stats.norm.isf(alpha / (2 * max(m, 1))))
    flagged: dict[tuple[str, str], dict[str, Any]] = {}
    for serial, name, test, k, z in tests:
        if abs(z) > z_crit:
            f = flagged.setdefault((serial, name), {"steps": [], "trend": False})
            if test == "step":
                f["steps"].append(k)
            else:
                f["trend"] = True
    flags = []
    for (serial, name), f in sorted(flagged.items()):
        e = robots[serial]["parameters"][name]
        dates = robots[serial]["dates"]
        n = len(e["value"])
        if n < 3:
            kind = "jump"
        else:
            best = min(e["line_chi2"], e["step_chi2"])
            if stats.chi2.sf(best, n - 2) < pattern_alpha:
                kind = "change"
            else:
                kind = "drift" if e["line_chi2"] < e["step_chi2"] else "jump"
        k_max = int(np.argmax(np.abs(e["step_z"])))
        flag = {
            "serial": serial,
            "parameter": name,
            "unit": e["unit"],
            "kind": kind,
            "steps_flagged": [[dates[k], dates[k + 1]] for k in f["steps"]],
            "largest_step": {
                "between": [dates[k_max], dates[k_max + 1]],
                "delta": e["value"][k_max + 1] - e["value"][k_max],
                "z": e["step_z"][k_max],
            },
            "total_change": e["value"][-1] - e["value"][0],
            "trend_z": e.get("trend_z"),
            "slope_per_year": e.get("slope_per_year"),
            "explanation": explain(kind, name, e["unit"], dates, f, e),
        }
        flags.append(flag)
    return {
        "test": {
            "alpha": alpha,
            "n_tests": m,
            "z_critical": z_crit,
            "kinds": list(kinds),
            "pattern_alpha": pattern_alpha,
            "rule": (
                f"|z| > {z_crit:.3f}: two-sided normal tests (steps between consecutive accepted calibrations, "
                f"z = Δ/sqrt(se1² + se2²); weighted trend slope over its standard error), Bonferroni over {m} tests "
                f"at family-wise false-flag rate {alpha:g}"
            ),
        },
        "flags": flags,
        "robots": robots,
    }


def explain(kind: str, name: str, unit: str, dates: Sequence[str], f: Mapping[str, Any], e: Mapping[str, Any]) -> str:
    """A sentence on what a flag may mean."""
    zero_offset = name.startswith("theta")
    if kind == "jump":
        k = int(np.argmax(np.abs(e["step_z"])))
        a, b = dates[k], dates[k + 1]
        d = e["value"][k + 1] - e["value"][k]
        what = (
            "the joint's zero offset jumped: typical of a motor, encoder or resolver change, a lost reference or a "
            "crash; check the maintenance log"
            if zero_offset
            else "a step change of the geometry: a crash, a remounted or replaced part, an axis re-adjusted"
        )
        return f"{name} changed by {d:+.4g} {unit} between {a} and {b}: {what}. The later calibration includes it."
    if kind == "drift":
        return (
            f"{name} drifts steadily by {e['slope_per_year']:+.4g} {unit}/year over {dates[0]} .. {dates[-1]}: "
            "wear (gear or bearing play), creep, or a slowly changing compliance; recalibrate more often or plan "
            "maintenance"
        )
    return (
        f"{name} moved more than its standard errors allow over {dates[0]} .. {dates[-1]} without a single step "
        "or a steady trend: look at the campaigns (tracker set-up, reflector, temperature) and the robot's log"
    )


def truth_score(flags: Sequence[Mapping[str, Any]], truth: Mapping[str, Any]) -> dict[str, Any]:
    """Compare flags with the twin's planted events (``FLEET_DIR/truth.json``): every event flagged on its
    parameter with its kind, and the flags on robots or parameters without an event (false flags)."""
    planted = {
        (serial, e["parameter"]): e["kind"]
        for serial, r in truth.get("robots", {}).items()
        for e in r.get("events", [])
    }
    found = {(f["serial"], f["parameter"]): f["kind"] for f in flags}
    detected = [k for k in planted if k in found]
    right_kind = [k for k in detected if found[k] == planted[k]]
    false = sorted(k for k in found if k not in planted)
    return {
        "n_events": len(planted),
        "n_detected": len(detected),
        "n_right_kind": len(right_kind),
        "missed": sorted(f"{s}:{p}" for s, p in planted if (s, p) not in found),
        "wrong_kind": sorted(
            f"{s}:{p} ({found[(s, p)]} vs {planted[(s, p)]})" for s, p in detected if (s, p) not in right_kind
        ),
        "n_false_flags": len(false),
        "false_flags": [f"{s}:{p}" for s, p in false],
        "n_robots_without_event": len(truth.get("robots", {})) - len({s for s, _ in planted}),
    }
