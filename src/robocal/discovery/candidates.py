"""The library of candidate effects: physical cause, signals, and regressor in error-Jacobian form.

Every candidate adds a few coefficients ``c`` to the calibration model. Three shapes:

- ``joint``: a joint-angle error ``dq_j(row) = S(row) · c`` on one joint (compliance: ``S`` = torque, current or
  gravity torque; gear: ``sin(h q_j), cos(h q_j)``; backlash: the approach direction ``dir_j``). Its regressor is
  the position Jacobian column of joint ``j`` times the signal: ``dp = J_q[:, :, j] · S c``.
- ``param``: per-row drift of calibration parameters ``x_i(row) = x_i + S_i(row) · c_i`` (thermal: every
  identifiable parameter follows the temperature signals; drift: the tracker/base frame moves with time).
  Regressor ``J_x[:, :, i] · S_i``. The drift is small, so the extended model adds it to first order.
- ``frame``: the robot base or the tool rotating / moving in proportion to a logged signal (extra column of the
  campaign, :mod:`robocal.discovery.logged`), first order like a parameter drift.
- ``structure``: a kinematic parameter the model leaves out (Hayati ``beta`` on a parallel joint pair).
- ``axis``: a linear axis's carriage error along its travel (a track's straightness, a column's bending), first
  order like a parameter drift: :mod:`robocal.discovery.axes`.
- ``tracker``: the tracker's length scale ``p_meas = (1 + s(row)) p_true`` about the tracker head, ``s(row) =
  S(row) · c`` (ppm): regressor ``S(row) p_mm(row)`` on the position residuals (measurement side). A constant
  scale is a uniform scale of the robot's lengths and base, which no calibration without a reference length can
  tell apart: only a scale changing with time or air temperature is a candidate (the constant is listed as
  skipped, with that reason).
  A scale changing with time is also a proxy for a robot effect whose signal follows time (a payload put on
  halfway, a warm-up): when its signal correlates with the payload or a temperature, the F-test search scores it
  but leaves it to the cross-validated selection (``extra["selection"] == "cv"``), which offers it after the
  robot's own effects were found.

All signals are built for every row of the campaign (calibration and validation), so the extended model
can predict held-out rows. A candidate whose signal is missing or does not vary is returned in the skipped list
with the reason.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from robocal.data.contract import Campaign
from robocal.discovery.config import DiscoveryConfig
from robocal.discovery.dictionary import TermColumns
from robocal.discovery.sessions import THERMAL_WITHIN_SESSIONS, temperature_share_within_sessions
from robocal.robot import RobotDescription

HOUR_S = 3600.0
#: A tracker's length scale is reported in parts per million (the S column of a ``tracker`` candidate is per ppm).
PPM = 1e-6


@dataclass(frozen=True)
class Candidate:
    """One candidate effect.

    key : unique id (``gear:j4:h1``); effect : family name; joint / harmonic : 1-based or None;
    cause : the physical cause; signal : what drives it; shape : ``joint`` | ``param`` | ``structure`` |
    ``tracker``;
    S : (m_all, k) signal matrix for ``joint`` shape, (m_all, s) for ``param`` (one coefficient per
    parameter and signal column), (m_all, k) for ``tracker`` (the scale per unit of each coefficient);
    coef_names : names of the coefficients (for ``param`` shape filled when the model's parameters are known);
    coef_units : their units; scale : display factor per coefficient.
    """

    key: str
    effect: str
    joint: int | None
    harmonic: int | None
    cause: str
    signal: str
    shape: str
    S: np.ndarray | TermColumns  # a proposed equation's: the dictionary's columns, formed when read
    coef_names: tuple[str, ...] = ()
    coef_units: tuple[str, ...] = ()
    params: tuple[str, ...] = ()  # param shape: which calibration parameters drift ("*identified*" = all)
    signal_names: tuple[str, ...] = ()
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def label(self) -> str:
        if self.effect == "axis":  # a linear axis's error: its name says it (track:straightness_y)
            return self.key
        out = self.effect
        if self.joint is not None:
            out += f" joint {self.joint}"
        if self.harmonic is not None:
            out += f" harmonic {self.harmonic}"
        return out


@dataclass(frozen=True)
class SkippedCandidate:
    key: str
    effect: str
    joint: int | None
    reason: str

    def to_dict(self) -> dict[str, Any]:
        return {"key": self.key, "effect": self.effect, "joint": self.joint, "reason": self.reason}


def _varies(x: np.ndarray, tol: float) -> bool:
    return bool(np.all(np.isfinite(x)) and np.std(x) > tol)


def compliance_signal(campaign: Campaign, robot: RobotDescription, j: int) -> tuple[np.ndarray | None, str, str, str]:
    """Signal for the compliance of joint ``j`` (0-based): reported torque, else current, else gravity torque.

    Returns ``(values (m,), description, coefficient unit, why None)``.
    """
    if campaign.tau_Nm is not None:
        return campaign.tau_Nm[:, j], f"reported torque tau{j + 1}_Nm", "rad/N·m", ""
    if campaign.current_A is not None:
        return campaign.current_A[:, j], f"motor current i{j + 1}_A", "rad/A", ""
    if robot.has_dynamics:
        from robocal.kinematics.gravity import gravity_torques

        tau = gravity_torques(robot, campaign.q, campaign.payload_kg)
        return tau[:, j], "gravity torque from link masses and payload (robot description)", "rad/N·m", ""
    return None, "", "", "no torques, no currents and no link masses (dynamics) in the robot description"


def _temperature_signals(campaign: Campaign, n_comp: int) -> tuple[np.ndarray, tuple[str, ...], str]:
    """Principal components of the rows' temperature changes (°C), up to ``n_comp`` with real variance."""
    assert campaign.temperatures is not None
    T = np.asarray(campaign.temperatures, dtype=float)
    dT = T - T.mean(axis=0)
    _U, s, Vt = np.linalg.svd(dT, full_matrices=False)
    # keep components above the sensor-noise level: a singular value must exceed 1 % of the first
    keep = [k for k in range(min(n_comp, len(s))) if s[k] > 0.01 * s[0]]
    S = dT @ Vt[keep].T  # (m, k) °C
    names = tuple(f"PC{k + 1}" for k in keep)
    load = "; ".join(
        f"PC{k + 1} = " + " + ".join(f"{Vt[k, i]:.2f}·{campaign.sensor_names[i]}" for i in range(len(Vt[k])))
        for k in keep
    )
    return S, names, load


#: A measurement-side signal correlating more than this with a robot-side one is left to the cross-validated
#: selection (see the module docstring).
CONFOUND_CORR = 0.5


def _confounded(S: np.ndarray, campaign: Campaign) -> dict[str, Any]:
    """``{"selection": "cv", "confounded_with": name}`` when a column of ``S`` correlates (|r| > CONFOUND_CORR)
    with the payload or a logged temperature, else ``{}``."""
    robot_side = {"payload_kg": np.asarray(campaign.payload_kg, dtype=float)}
    if campaign.temperatures is not None:
        T = np.asarray(campaign.temperatures, dtype=float)
        robot_side.update({n: T[:, k] for k, n in enumerate(campaign.sensor_names)})
    for name, x in robot_side.items():
        if not _varies(x, 1e-9):
            continue
        for col in S.T:
            if _varies(col, 1e-12) and abs(float(np.corrcoef(col, x)[0, 1])) > CONFOUND_CORR:
                return {"selection": "cv", "confounded_with": name}
    return {}


#: The signals a tracker's scale may follow: coefficient name -> (description, unit).
_SCALE_SIGNALS = {
    "ppm_per_h": ("time (h from the campaign's mean time)", "ppm/h"),
    "ppm_per_degC_air": ("air temperature (degC from its mean)", "ppm/degC"),
}


def _air_temperature(campaign: Campaign, robot: RobotDescription) -> tuple[list[str], np.ndarray | None]:
    """The names of the sensors with ``location: ambient`` and the mean of those logged (degC per row), or None
    without one."""
    ambient = [x.name for x in robot.sensors if x.location == "ambient"]
    logged = list(campaign.sensor_names) if campaign.temperatures is not None else []
    cols = [logged.index(a) for a in ambient if a in logged]
    if not cols or campaign.temperatures is None:
        return ambient, None
    return ambient, np.asarray(campaign.temperatures, dtype=float)[:, cols].mean(axis=1)


def _parallel_joints(robot: RobotDescription) -> list[int]:
    """0-based joints ``j`` whose axis is parallel to the next one (MD-H ``alpha_{j+1}`` ≡ 0 mod π)."""
    if not robot.is_mdh:
        return []
    out = []
    for j in range(robot.n_joints - 1):
        a = float(np.mod(robot.alpha[j + 1], np.pi))
        if min(a, np.pi - a) < np.deg2rad(1.0):
            out.append(j)
    return out


def build_library(
    campaign: Campaign, robot: RobotDescription, cfg: DiscoveryConfig
) -> tuple[list[Candidate], list[SkippedCandidate]]:
    """Every candidate of the configured effects for this campaign, and the skipped ones with reasons."""
    out = _Library([], [])
    for effect in cfg.effects:
        build = _EFFECT_CANDIDATES.get(effect)
        if build is not None:
            build(campaign, robot, cfg, out)
    if robot.has_prismatic:  # a track's or a column's own errors along its travel (robocal.discovery.axes)
        from robocal.discovery.axes import axis_candidates

        specs, skipped = axis_candidates(campaign, robot)
        out.cands += [Candidate(**k) for k in specs]
        out.skipped += [SkippedCandidate(*s) for s in skipped]
    return out.cands, out.skipped


@dataclass
class _Library:
    """The candidates built so far and the skipped ones, in the order of the configured effects."""

    cands: list[Candidate]
    skipped: list[SkippedCandidate]


def _compliance_candidates(campaign: Campaign, robot: RobotDescription, cfg: DiscoveryConfig, out: _Library) -> None:
    """The ``compliance`` candidates of the campaign, or why there are none."""
    effect = "compliance"
    n = robot.n_joints
    tol = cfg.min_signal_std
    for j in range(n):
        key = f"compliance:j{j + 1}"
        sig, desc, unit, why = compliance_signal(campaign, robot, j)
        if sig is None:
            out.skipped.append(SkippedCandidate(key, effect, j + 1, why))
        elif not _varies(sig, max(tol, 1e-6)):
            out.skipped.append(SkippedCandidate(key, effect, j + 1, f"the signal ({desc}) does not vary"))
        else:
            out.cands.append(
                Candidate(
                    key, effect, j + 1, None,
                    cause=f"torsional elasticity of the joint-{j + 1} reducer under load (dq = c·tau)",
                    signal=desc, shape="joint", S=sig[:, None],
                    coef_names=("c",), coef_units=(unit,),
                    extra={"source": "torque" if desc.startswith("reported torque") else
                           "current" if desc.startswith("motor current") else "gravity"},
                )
            )  # fmt: skip


def _gear_candidates(campaign: Campaign, robot: RobotDescription, cfg: DiscoveryConfig, out: _Library) -> None:
    """The ``gear`` candidates of the campaign, or why there are none."""
    effect = "gear"
    from robocal.compensation.signals import held_harmonic_signal

    q = campaign.q
    cal_rows = campaign.split == "calibration" if np.any(campaign.split == "validation") else slice(None)
    for j in range(robot.n_joints):
        rng = float(np.ptp(q[:, j]))
        lo, hi = (float(np.rad2deg(f(q[cal_rows, j]))) for f in (np.min, np.max))
        for h in cfg.gear_harmonics:
            key = f"gear:j{j + 1}:h{h}"
            if rng < 1e-6 or robot.prismatic[j]:  # a linear axis's mm have no harmonics (its travel: axis errors)
                why = f"joint {j + 1} " + ("is a linear axis" if robot.prismatic[j] else "does not move")
                out.skipped.append(SkippedCandidate(key, effect, j + 1, why))
                continue
            # harmonics 1-2 (eccentricity) are one revolution's error: evaluated everywhere when the
            # calibration visited a whole period of the harmonic; over less, the harmonic is a smooth
            # trend there and is held at its values at the visited range's ends outside it (unlike the
            # transmission error's many harmonics, which fall to zero: robocal.compensation.signals)
            held = [lo, hi] if hi - lo < 360.0 / h else None
            S = held_harmonic_signal(q[:, j], h, held)
            out.cands.append(
                Candidate(
                    key, effect, j + 1, int(h),
                    cause=f"periodic transmission error of the joint-{j + 1} reducer, harmonic {h} "
                    "of the joint angle",
                    signal=f"sin/cos({h}·q{j + 1})", shape="joint", S=S,
                    coef_names=("sin", "cos"), coef_units=("rad", "rad"),
                    extra={"joint_range_deg": float(np.rad2deg(rng)), "held_outside_deg": held},
                )
            )  # fmt: skip


def _backlash_candidates(campaign: Campaign, robot: RobotDescription, cfg: DiscoveryConfig, out: _Library) -> None:
    """The ``backlash`` candidates of the campaign, or why there are none."""
    effect = "backlash"
    n = robot.n_joints
    for j in range(n):
        key = f"backlash:j{j + 1}"
        if campaign.direction is None:
            out.skipped.append(SkippedCandidate(key, effect, j + 1, "no approach directions (dir1..dirN)"))
            continue
        d = campaign.direction[:, j].astype(float)
        if not _varies(d, 1e-9):
            out.skipped.append(
                SkippedCandidate(key, effect, j + 1, f"every pose approached joint {j + 1} the same way")
            )
            continue
        out.cands.append(
            Candidate(
                key, effect, j + 1, None,
                cause=f"dead band of the joint-{j + 1} drive: the joint lags against its approach direction",
                signal=f"approach direction dir{j + 1}", shape="joint", S=d[:, None],
                coef_names=("half_band",), coef_units=("rad",),
            )
        )  # fmt: skip


def _thermal_candidates(campaign: Campaign, robot: RobotDescription, cfg: DiscoveryConfig, out: _Library) -> None:
    """The ``thermal`` candidates of the campaign, or why there are none."""
    effect = key = "thermal"
    tol = cfg.min_signal_std
    if campaign.temperatures is None:
        out.skipped.append(SkippedCandidate(key, effect, None, "no temperature log (temperatures.csv)"))
        return
    T = np.asarray(campaign.temperatures, dtype=float)
    if not np.all(np.isfinite(T)) or float(np.max(np.std(T, axis=0))) < max(tol, 0.05):
        out.skipped.append(
            SkippedCandidate(key, effect, None, "the temperatures do not vary (a constant offset is a pure "
                             "length scale, absorbed by the geometry)")
        )  # fmt: skip
        return
    within = temperature_share_within_sessions(campaign, T)
    if within is not None and within < THERMAL_WITHIN_SESSIONS:
        out.skipped.append(SkippedCandidate(key, effect, None, f"the temperatures change between the sessions "
                           f"(tracker stations) and hardly within one ({within:.1%} of their variance within): a "
                           "thermal model would be the sessions' own difference (a tool re-seated, the tracker's "
                           "frame), confounded with them; the session effects are offered instead"))  # fmt: skip
        return
    S, names, load = _temperature_signals(campaign, cfg.thermal_components)
    out.cands.append(
        Candidate(
            key, effect, None, None,
            cause="thermal expansion and tilt: every identifiable parameter (base and tool included) drifts "
            "linearly with the temperature signals",
            signal=f"temperature principal components ({load})", shape="param", S=S,
            params=("*identified*",), signal_names=names,
        )
    )  # fmt: skip


def _drift_candidates(campaign: Campaign, robot: RobotDescription, cfg: DiscoveryConfig, out: _Library) -> None:
    """The ``drift`` candidates of the campaign, or why there are none."""
    effect = "drift"
    key = "drift"
    t = np.asarray(campaign.timestamp_s, dtype=float)
    if not _varies(t, 1.0):
        out.skipped.append(SkippedCandidate(key, effect, None, "the timestamps do not vary"))
        return
    S = ((t - t.mean()) / HOUR_S)[:, None]
    out.cands.append(
        Candidate(
            key, effect, None, None,
            cause="tracker or robot base moving over the campaign (tripod settling, floor): the tracker-to-"
            "base frame drifts linearly in time",
            signal="timestamp (h from the campaign's mean time)", shape="param", S=S,
            params=("base_tx", "base_ty", "base_tz", "base_rx", "base_ry", "base_rz"), signal_names=("t_h",),
        )
    )  # fmt: skip


def _regap_candidates(campaign: Campaign, robot: RobotDescription, cfg: DiscoveryConfig, out: _Library) -> None:
    """The ``regap`` candidates of the campaign, or why there are none."""
    effect = "regap"
    key = "regap"
    t = np.asarray(campaign.timestamp_s, dtype=float)
    cal_rows = campaign.split == "calibration" if np.any(campaign.split == "validation") else slice(None)
    tc = np.sort(t[cal_rows])
    gaps = np.diff(tc)
    big = np.flatnonzero(gaps > cfg.registration_gap_h * HOUR_S)
    if len(big) == 0:
        out.skipped.append(SkippedCandidate(key, effect, None, f"no gap of more than {cfg.registration_gap_h} h "
                                        "between measurements"))  # fmt: skip
        return
    big = np.sort(big[np.argsort(-gaps[big])][:3])  # the three longest gaps at most
    cuts = [(tc[k] + tc[k + 1]) / 2.0 for k in big]
    S = np.column_stack([(t > c).astype(float) for c in cuts])
    S = S - S[cal_rows].mean(axis=0)
    names = tuple(f"after_gap{i + 1}" for i in range(len(cuts)))
    out.cands.append(
        Candidate(
            key, effect, None, None,
            cause="the tracker was set up again (or bumped) during a pause: after each gap of more than "
            f"{cfg.registration_gap_h} h the tracker-to-base frame is a fresh registration (a measurement-"
            "side effect, never sent to the controller)",
            signal="measured after the gap(s) at " + ", ".join(f"{c / HOUR_S:.1f} h" for c in cuts),
            shape="param", S=S,
            params=("base_tx", "base_ty", "base_tz", "base_rx", "base_ry", "base_rz"), signal_names=names,
        )
    )  # fmt: skip


def _air_candidates(campaign: Campaign, robot: RobotDescription, cfg: DiscoveryConfig, out: _Library) -> None:
    """The ``air`` candidates of the campaign, or why there are none."""
    effect = "air"
    tol = cfg.min_signal_std
    key = "air"
    ambient, Ta = _air_temperature(campaign, robot)
    if Ta is None:
        why = "no air temperature (a sensor with location: ambient in the robot description) in the log"
        out.skipped.append(SkippedCandidate(key, effect, None, why))
        return
    if not np.all(np.isfinite(Ta)) or float(np.std(Ta)) < max(tol, 0.05):
        out.skipped.append(SkippedCandidate(key, effect, None, "the air temperature does not vary"))
        return
    out.cands.append(
        Candidate(
            key, effect, None, None,
            cause="the tracker's frame moves with the air temperature (its stand, the air's refractive "
            "index compensation): a measurement-side effect, never sent to the controller",
            signal=f"air temperature ({', '.join(ambient)}) from its mean, degC", shape="param",
            S=(Ta - Ta.mean())[:, None],
            params=("base_tx", "base_ty", "base_tz", "base_rx", "base_ry", "base_rz"), signal_names=("T_air",),
        )
    )  # fmt: skip


def _scale_candidates(campaign: Campaign, robot: RobotDescription, cfg: DiscoveryConfig, out: _Library) -> None:
    """The ``scale`` candidates of the campaign, or why there are none."""
    effect = "scale"
    tol = cfg.min_signal_std
    t = np.asarray(campaign.timestamp_s, dtype=float)
    out.skipped.append(SkippedCandidate("scale", effect, None, "a constant tracker scale is a uniform scale of the "
                                    "robot's lengths and base: absorbed by the geometric calibration, not "
                                    "separable without a reference length (only a scale that changes "
                                    "during the campaign is tested)"))  # fmt: skip
    cols: list[np.ndarray] = []
    sig_names: list[str] = []
    if _varies(t, 1.0):
        cols.append((t - t.mean()) / HOUR_S)
        sig_names.append("ppm_per_h")
    _, Ta = _air_temperature(campaign, robot)
    if Ta is not None and _varies(Ta, max(tol, 0.05)):
        cols.append(Ta - Ta.mean())
        sig_names.append("ppm_per_degC_air")
    if not cols:
        why = "neither the timestamps nor an air temperature vary"
        out.skipped.append(SkippedCandidate("scale:drift", effect, None, why))
        return
    out.cands.append(
        Candidate(
            "scale:drift", effect, None, None,
            cause="the tracker's length scale changes during the campaign (the air's refractive index as "
            "the weather changes, a stale weather station): a measurement-side effect, never sent to the "
            "controller",
            signal=" and ".join(_SCALE_SIGNALS[n][0] for n in sig_names),
            shape="tracker", S=np.column_stack(cols) * PPM,
            coef_names=tuple(sig_names), coef_units=tuple(_SCALE_SIGNALS[n][1] for n in sig_names),
            extra={"p_mm": campaign.p_mm, **_confounded(np.column_stack(cols), campaign)},
        )
    )  # fmt: skip


def _beta_candidates(campaign: Campaign, robot: RobotDescription, cfg: DiscoveryConfig, out: _Library) -> None:
    """The ``beta`` candidates of the campaign, or why there are none."""
    effect = "beta"
    par = _parallel_joints(robot)
    if not robot.is_mdh:
        out.skipped.append(SkippedCandidate("beta", effect, None, "POE robot: the twists already carry any tilt"))
    elif not par:
        out.skipped.append(SkippedCandidate("beta", effect, None, "no parallel consecutive joint axes"))
    for j in par:
        key = f"beta:j{j + 1}"
        if bool(robot.beta_free[j]):
            out.skipped.append(SkippedCandidate(key, effect, j + 1, f"beta{j + 1} is already in the model"))
            continue
        if any(p in (f"beta{j + 1}", "beta*") for p in cfg.fixed):
            out.skipped.append(SkippedCandidate(key, effect, j + 1, f"beta{j + 1} is fixed by the settings"))
            continue
        out.cands.append(
            Candidate(
                key, effect, j + 1, None,
                cause=f"axes {j + 1} and {j + 2} are not exactly parallel (Hayati tilt beta{j + 1})",
                signal="geometry", shape="structure", S=np.zeros((campaign.n_rows, 0)),
                coef_names=(f"beta{j + 1}",), coef_units=("rad",),
            )
        )  # fmt: skip


def _signal_candidates(campaign: Campaign, robot: RobotDescription, cfg: DiscoveryConfig, out: _Library) -> None:
    """The ``signal`` candidates: every usable logged signal (extra numeric column, screened by
    :mod:`robocal.discovery.logged`) as a driver of the four frame effects, the tracker's scale and a joint offset
    per moving joint; the columns not used go to the skipped list with their reason."""
    from robocal.discovery.logged import FRAME_WORDS, offered_frames, screen

    used, skipped = screen(campaign, robot)
    for s in skipped:
        out.skipped.append(SkippedCandidate(f"signal:{s['column']}", "signal", None, s["reason"]))
    cal = campaign.split == "calibration" if np.any(campaign.split == "validation") else slice(None)
    for sig in used:
        S = (sig.values - sig.centre)[:, None]
        unit = sig.unit or "unit"
        what = (
            f"logged signal {sig.name}"
            + (f" ({sig.unit})" if sig.unit else "")
            + ("" if sig.declaration is not None else ", undeclared")
        )
        info = {
            "column": sig.name,
            "centre": sig.centre,
            "range": [float(np.min(sig.values[cal])), float(np.max(sig.values[cal]))],  # fitted on (the service)
            "side": sig.side,
            "signal_info": sig.to_dict(),
            "target": campaign.target,
        }
        for frame, (names, cu), carried in offered_frames(campaign, robot):
            out.cands.append(
                Candidate(
                    f"signal:{sig.name}:{frame}", "signal", None, None,
                    cause=FRAME_WORDS[frame].format(s=sig.name), signal=what, shape="frame", S=S,
                    coef_names=names, coef_units=tuple(f"{cu}/{unit}" for _ in names),
                    extra={**info, "frame": frame, **carried},
                )
            )  # fmt: skip
        out.cands.append(
            Candidate(
                f"signal:{sig.name}:scale", "signal", None, None,
                cause=f"the tracker's length scale follows {sig.name} (the air's refractive index, the tracker's "
                "own temperature): a measurement-side effect, never sent to the controller", signal=what,
                shape="tracker", S=S * PPM, coef_names=("ppm",), coef_units=(f"ppm/{unit}",),
                extra={**info, "frame": None, "side": "measurement", "p_mm": campaign.p_mm},
            )
        )  # fmt: skip
        for j in range(robot.n_joints):
            if float(np.ptp(campaign.q[:, j])) < 1e-6:
                continue
            slide, u = (True, "mm") if robot.prismatic[j] else (False, "rad")  # a linear axis: its mm (pass 14)
            out.cands.append(
                Candidate(
                    f"signal:{sig.name}:j{j + 1}", "signal", j + 1, None,
                    cause=f"the joint-{j + 1} {'position' if slide else 'angle'} is offset in proportion to "
                    f"{sig.name} (an encoder or {'drive' if slide else 'reducer'} reading the signal's cause)",
                    signal=what, shape="joint", S=S, coef_names=("c",), coef_units=(f"{u}/{unit}",),
                    extra={**info, "frame": None},
                )
            )  # fmt: skip
    # every two signals moving one frame, offered together (shape ``pair``: scored on both members' columns, accepted
    # as the two): a tilt a two-axis inclinometer reads splits over its two columns, each alone explaining only its
    # axis's share (a stand tilting ~1 mrad: 21 % each), and the compliance of joint 2 (50 %) was named instead
    frames = [c for c in out.cands if c.shape == "frame" and c.effect == "signal"] if len(used) <= MAX_PAIRED else []
    for k, ca in enumerate(frames):
        for cb in (c for c in frames[k + 1 :] if c.extra["frame"] == ca.extra["frame"]):
            a, b = ca.extra["column"], cb.extra["column"]
            out.cands.append(Candidate(
                f"signal:{a}+{b}:{ca.extra['frame']}", "signal", None, None, cause=f"{ca.cause}; and with {b}",
                signal=f"{ca.signal} and {cb.signal}", shape="pair", S=np.column_stack([ca.S, cb.S]),
                coef_names=tuple(f"{a}:{n}" for n in ca.coef_names) + tuple(f"{b}:{n}" for n in cb.coef_names),
                coef_units=ca.coef_units + cb.coef_units, extra={"members": (ca, cb), "frame": ca.extra["frame"]},
            ))  # fmt: skip


#: the logged signals are offered in pairs (a frame moving with two of them) when there are at most this many
MAX_PAIRED = 6
#: a session (tracker station) is offered its own tool with at least this many rows (the sessions that the
#: leave-one-session-out selection holds out, robocal.discovery.session_cv.MIN_SESSION_ROWS)
SESSION_MIN_ROWS = 20


def _session_candidates(campaign: Campaign, robot: RobotDescription, cfg: DiscoveryConfig, out: _Library) -> None:
    """The ``session`` candidates: in a campaign of several sessions (tracker stations of at least
    :data:`SESSION_MIN_ROWS` rows), the tool re-seated in each session after the first — every target moved on the
    flange by the session's own ``(tx, ty, tz)`` mm, as a tool taken off and put back, a nest re-glued, a new
    reflector do. Like the session's tracker frame it belongs to the session: not sent to the controller, and a
    new session re-measures it (the session validation's ``tool`` registration)."""
    if not campaign.has_stations:
        return
    st = np.asarray(campaign.station).astype(str)
    big = [s for s in campaign.station_names if int(np.sum(st == s)) >= SESSION_MIN_ROWS]
    if len(big) < 2:
        why = f"fewer than two sessions (tracker stations) of >= {SESSION_MIN_ROWS} rows"
        out.skipped.append(SkippedCandidate("session:tool", "session", None, why))
        return
    ref = campaign.station_names[0]
    for s in big:
        if s == ref:
            continue
        out.cands.append(
            Candidate(
                f"session:{s}:tool", "session", None, None,
                cause=f"the tool re-seated in session {s}: every target sits elsewhere on the flange than in session "
                f"{ref} (taken off and put back, a nest re-glued); the session's own, like its tracker frame, and "
                "re-measured in a new session", signal=f"session {s} (the station column)", shape="frame",
                S=(st == s).astype(float)[:, None], coef_names=("tx", "ty", "tz"), coef_units=("mm", "mm", "mm"),
                extra={"column": "station", "centre": 0.0, "side": "session", "frame": "tool_trans", "station": s,
                       "reference": ref, "target": campaign.target},
            )
        )  # fmt: skip


#: the candidate builder of each library effect (an effect not listed has no candidates of its own here)
_EFFECT_CANDIDATES: dict[str, Callable[..., None]] = {
    "compliance": _compliance_candidates,
    "gear": _gear_candidates,
    "backlash": _backlash_candidates,
    "thermal": _thermal_candidates,
    "drift": _drift_candidates,
    "regap": _regap_candidates,
    "air": _air_candidates,
    "scale": _scale_candidates,
    "beta": _beta_candidates,
    "signal": _signal_candidates,
    "session": _session_candidates,
}


def with_beta(robot: RobotDescription, joint: int) -> RobotDescription:
    """The robot with Hayati ``beta`` of ``joint`` (1-based) made a calibration parameter."""
    free = np.array(robot.beta_free, dtype=bool).copy()
    free[joint - 1] = True
    return replace(robot, beta_free=free)
