"""Discovery's candidates for an external axis's own errors (issue 34): shape ``axis``.

A robot with a linear axis (a prismatic joint: a track, a lifting column) is offered, per axis, the errors of its
carriage along the travel (:mod:`robocal.kinematics.axes`): ``<role>:straightness_x``, ``<role>:straightness_y``,
``<role>:positioning``, ``<role>:pitch``, ``<role>:yaw``, ``<role>:roll`` (``role`` the joint's ``role`` key, e.g.
``track``), each a Legendre series over the travel from the lowest order the kinematic parameters do not hold
(:data:`robocal.calibration.axes.LOWEST_ORDER`) to :data:`robocal.calibration.axes.ORDER`; and for a
column (role ``column``) ``column:bending``: the carriage turning about its x and y in proportion to the moment of
the carried weight, and (with masses in the description) that compliance growing with the extension; without
masses the moment is unknown but linear in the carried bodies' masses and first moments
(:func:`robocal.kinematics.axes.moment_features`), one coefficient per mass parameter, as the calibration's axis
fit does. The
candidates are offered whenever the robot has a linear axis (no setting: a robot without one gets none, and its
discovery is unchanged).

Regressor of a coefficient ``k``: the carriage error element's column (the derivative of the point by the element,
from the chain augmented with the six elements, :func:`robocal.kinematics.axes.augment`) times the coefficient's
feature ``S[:, k]``; first order, like a parameter drift (an error of 0.3 mm and 100 urad leaves ~3e-5 mm).
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

from robocal.calibration.axes import BENDING, KNM, LOWEST_ORDER, ORDER, mass_parameter_names
from robocal.data.contract import Campaign
from robocal.identification.model import CalibrationModel, FitData, with_base
from robocal.kinematics.axes import (
    COMPONENTS,
    UNITS,
    augment,
    carried_moment,
    legendre,
    moment_features,
    rod_moment,
    travel_coordinate,
)
from robocal.robot import RobotDescription


def axis_candidates(
    campaign: Campaign, robot: RobotDescription, order: int = ORDER
) -> tuple[list[dict[str, Any]], list[tuple[str, str, int, str]]]:
    """The ``axis`` candidates of every linear axis of ``robot`` (the keyword arguments of each
    :class:`robocal.discovery.candidates.Candidate`), Legendre orders up to ``order``, and the skipped ones
    ``(key, effect, joint, reason)``."""
    cands: list[dict[str, Any]] = []
    skipped: list[tuple[str, str, int, str]] = []
    for j in (int(v) for v in np.flatnonzero(robot.prismatic)):
        role = robot.role(j)
        s = campaign.q[:, j]
        if float(np.ptp(s)) < 1e-6:
            skipped.append((f"{role}:*", "axis", j + 1, f"the axis (joint {j + 1}) does not move"))
            continue
        u = travel_coordinate(s, robot.q_limits[j])
        for c, comp in enumerate(COMPONENTS):
            orders = range(LOWEST_ORDER[comp], order + 1)
            S = np.column_stack([legendre(u, k) for k in orders])
            unit = "mm" if UNITS[c] == "mm" else "rad"
            cands.append(
                dict(
                    key=f"{role}:{comp}", effect="axis", joint=j + 1, harmonic=None,
                    cause=f"the {role}'s carriage {_WORDS[comp]} along its travel (joint {j + 1}): a smooth "
                    f"function of its position, Legendre orders {orders.start}..{orders.stop - 1}",
                    signal=f"Legendre polynomials of the joint-{j + 1} position over its travel", shape="axis", S=S,
                    coef_names=tuple(f"P{k}" for k in orders), coef_units=tuple(unit for _ in orders),
                    extra={"axis_joint": j, "slots": tuple(c for _ in orders), "role": role, "component": comp,
                           "q": campaign.q, "target": campaign.target},
                )
            )  # fmt: skip
        if "column" not in role:
            continue
        key = f"{role}:bending"
        cols: list[np.ndarray] = []
        slots: list[int] = []
        names: list[str] = []
        if robot.has_dynamics:
            cols, slots, names = _moment_columns(carried_moment(robot, campaign.q, j, campaign.payload_kg) / KNM, u, "")
            signal = ("moment of the carried weight about the carriage (description's masses, kN·m), and times the "
                      "extension")  # fmt: skip
        else:  # no masses: the moment per unknown mass parameter of the bodies carried (the calibration's axis fit)
            Mf, _ = moment_features(robot, campaign.q, j)
            for name, comp, ax in BENDING:
                for f, pn in enumerate(mass_parameter_names(robot, j)):
                    cols.append(Mf[:, ax, f])
                    slots.append(COMPONENTS.index(comp))
                    names.append(f"{name}_{pn}")
            signal = ("moment about the carriage of each unknown mass parameter of the bodies it carries (kN·m per kg "
                      "or per kg x 0.1 m; no masses in the description)")  # fmt: skip
            rcols, rslots, rnames = _moment_columns(rod_moment(robot, campaign.q, j, campaign.payload_kg), u, "_rods")
            cands.append(
                dict(
                    key=f"{role}:bending_rods", effect="axis", joint=j + 1, harmonic=None,
                    cause=f"the {role} bends under the arm's weight: its carriage turns about its x and y in "
                    "proportion to the moment of the weight it carries, more as it extends (the links' masses unknown: "
                    "shaped like the arm's, with the payload)",
                    signal="moment about the carriage of links shaped like the arm's (uniform rods) and the payload, "
                    "and times the extension", shape="axis", S=np.column_stack(rcols),
                    coef_names=tuple(rnames), coef_units=tuple("rad/kNm" for _ in rnames),
                    extra={"axis_joint": j, "slots": tuple(rslots), "role": role, "component": "bending",
                           "q": campaign.q, "target": campaign.target},
                )
            )  # fmt: skip
        cands.append(
            dict(
                key=key, effect="axis", joint=j + 1, harmonic=None,
                cause=f"the {role} bends under the arm's weight: its carriage turns about its x and y in proportion "
                "to the moment of the weight it carries" + (", more as it extends" if robot.has_dynamics else ""),
                signal=signal, shape="axis", S=np.column_stack(cols),
                coef_names=tuple(names), coef_units=tuple("rad/kNm" for _ in names),
                extra={"axis_joint": j, "slots": tuple(slots), "role": role, "component": "bending",
                       "q": campaign.q, "target": campaign.target},
            )
        )  # fmt: skip
    return cands, skipped


def _moment_columns(M: np.ndarray, u: np.ndarray, tag: str) -> tuple[list[np.ndarray], list[int], list[str]]:
    """A column's bending by one moment ``M (m, 3)`` (kN·m, carriage frame): per bending axis the moment and the
    moment times the extension ``u``, with their error elements and names (``bending_x<tag>``, ``..._ext``)."""
    cols, slots, names = [], [], []
    for name, comp, ax in BENDING:
        for k, suffix in ((0, ""), (1, "_ext")):
            cols.append(M[:, ax] * u**k)
            slots.append(COMPONENTS.index(comp))
            names.append(f"{name}{tag}{suffix}")
    return cols, slots, names


_WORDS = {
    "straightness_x": "deviates sideways (x)",
    "straightness_y": "deviates sideways (y)",
    "positioning": "is off along the travel",
    "pitch": "pitches (about its x)",
    "yaw": "yaws (about its y)",
    "roll": "rolls (about the travel)",
}

_AUGMENTED: dict[tuple[int, int], tuple[CalibrationModel, CalibrationModel]] = {}


def _augmented(base: CalibrationModel, joint: int) -> CalibrationModel:
    """``base`` with the six carriage error elements of ``joint`` as pseudo joints (cached per model object)."""
    hit = _AUGMENTED.get((id(base), joint))
    if hit is not None and hit[0] is base:
        return hit[1]
    model = copy.copy(base)
    model.chain = augment(base.chain, [joint])
    model.full_chain = with_base(model.chain)
    _AUGMENTED.clear()  # one model at a time: the discovery refits one model after another
    _AUGMENTED[(id(base), joint)] = (base, model)
    return model


def axis_rows(cand: Any, base: CalibrationModel, x: np.ndarray, data: FitData, rows: np.ndarray, d: int) -> np.ndarray:
    """``(m, d, k)`` regressor of an ``axis`` candidate on campaign rows ``rows`` at the model ``base`` with
    parameters ``x``, the joints of ``data`` (already corrected by the joint-level effects)."""
    j = int(cand.extra["axis_joint"])
    model = _augmented(base, j)
    n = base.chain.n_joints
    m = data.m
    q = np.concatenate([data.q, np.zeros((m, 6))], axis=1)
    J_q, W_q = model.joint_jacobians(x, data.with_q(q))
    S = cand.S[rows]
    slots = np.asarray(cand.extra["slots"], dtype=int)
    out = np.zeros((m, d, S.shape[1]))
    out[:, :3, :] = J_q[:, :, n + slots] * S[:, None, :]
    if d == 6 and W_q is not None:
        out[:, 3:, :] = W_q[:, :, n + slots] * S[:, None, :]
    return out


def with_calibrate_order(
    library: list[Any], campaign: Campaign, robot: RobotDescription, geo: Any
) -> tuple[list[Any], Any]:
    """The library with its axis candidates offered up to the Legendre order ``robocal calibrate``'s
    cross-validation picks for the axes' errors (:func:`robocal.calibration.axes.fit_axis_errors` on the geometric
    fit ``geo``), when above :data:`ORDER`: a rail the search followed to order 3 held out 0.2638 mm where calibrate,
    its order 4 chosen, gave 0.1879 (newcomer passes 17 and 18). Returns the library and calibrate's axis fit
    (None when none was made), which the validation's "as robocal calibrate" figure reads again."""
    if not robot.has_prismatic or not any(getattr(c, "effect", None) == "axis" for c in library):
        return library, None
    from dataclasses import replace

    from robocal.calibration.axes import fit_axis_errors
    from robocal.errors import ConfigError

    try:
        af = fit_axis_errors(campaign, geo)
    except (ConfigError, np.linalg.LinAlgError, ValueError):
        return library, None
    order = max((t.order for t in af.terms if t.feature == "legendre"), default=0)
    if order <= ORDER:
        return library, af
    specs = {k["key"]: k for k in axis_candidates(campaign, robot, order)[0]}
    return [replace(c, **specs[c.key]) if c.effect == "axis" and c.key in specs else c for c in library], af


def discovered_axis_fit(fit: Any, robot: RobotDescription, x: np.ndarray) -> Any:
    """The accepted ``axis`` effects of a discovery fit as an :class:`robocal.calibration.axes.AxisFit` (terms
    named as the identification names them, their coefficients and standard errors, the calibration vector
    ``x``), for :func:`robocal.compensation.axes.compensate_axes`; None when none was accepted."""
    from robocal.calibration.axes import AxisFit, term_named

    terms, coef, se = [], [], []
    for acc, sl in zip(fit.model.accepted, fit.model.slices, strict=True):
        c = acc.cand
        if c.shape != "axis":
            continue
        role = c.extra["role"]
        for k, name in enumerate(c.coef_names):
            full = f"{role}:{name}" if c.extra["component"] == "bending" else f"{c.key}_{name}"
            terms.append(term_named(robot, full))
            coef.append(float(fit.theta[sl][k]))
            se.append(float(fit.stderr(acc.coef_names[k])))
    if not terms:
        return None
    return AxisFit(
        terms=tuple(terms),
        coef=np.array(coef),
        stderr=np.array(se),
        covariance=np.diag(np.square(se)),
        x=np.asarray(x, dtype=float),
        order=max((t.order for t in terms if t.feature == "legendre"), default=0),
        bending=any(t.feature == "moment" for t in terms),
        cv=(),
        poorly_determined=(),
        not_identifiable=(),
    )
