"""The joint refit of discovery's search: geometry and accepted effects from the previous fit's parameters, with
the geometric calibration's eliminated parameters held, the user's ``discovery.fixed`` fixed and the calibration's
prior toward the nominal robot kept (a thin campaign's)."""

from __future__ import annotations

from typing import Any

import numpy as np

from robocal.discovery.config import DiscoveryConfig
from robocal.discovery.cv import clear_cache
from robocal.discovery.model import Accepted, ExtendedModel, Fit, fit_model
from robocal.identification.identifiability import ParameterSpec
from robocal.identification.model import FitData
from robocal.robot import RobotDescription


def refitter(
    robot: RobotDescription,
    cfg: DiscoveryConfig,
    geo: Any,
    data: FitData,
    rows: np.ndarray,
    sigma: float,
    sigma_rad: float,
) -> Any:
    """The joint refit of the search on the campaign rows ``rows`` (their fit data ``data``): geometry and the
    accepted effects, from the previous fit's parameters (:func:`start`), the geometry's eliminated parameters
    held and the user's ``discovery.fixed`` fixed, the calibration's prior kept (:func:`calibration_prior`)."""
    targets, T_ref = geo.model.target_names, geo.model.T_ref
    fixed = set(ParameterSpec.of(geo.model, cfg.fixed, "discovery.fixed").fixed)
    base_prior = bounded_poorly_determined(geo, calibration_prior(geo, cfg))
    lengths = {nm for nm, k, u in zip(geo.model.names, geo.model.kinds, geo.model.units, strict=True)
               if k == "kinematic" and u == "mm"}  # fmt: skip
    held = frozenset(e.name for e in geo.eliminated) | (held_poorly_determined(geo) - lengths)

    def refit(accepted: list[Accepted], prev: Fit | None) -> Fit:
        model = ExtendedModel(robot, targets, T_ref, accepted, like=geo.model, base_prior=base_prior)
        theta0 = start(model, prev, geo)
        return fit_model(model, theta0, data, rows, sigma, fixed, cfg.rank_tol, cfg.max_iter, sigma_rad=sigma_rad,
                         held=held)  # the geometry's: kept out  # fmt: skip

    return refit


def held_poorly_determined(geo: Any) -> frozenset[str]:
    """The parameters the geometric calibration held at their start because the data could not determine them
    (``fit.poorly_determined`` with ``action`` "held ...": ``poorly_determined: fix``): held in the discovery's
    refits too. Freed there, a column arm's single reflector on the wrist's axis let theta6 and alpha7 wander with
    the effects (newcomer pass 16: a7 34 mm, theta6 6.9 deg, held-out positions unchanged, compensation.csv
    turning the wrist by a median 9.7 deg and refusing 3 of 30 targets)."""
    return frozenset(_held_poor(geo))


def _held_poor(geo: Any) -> dict[str, dict[str, Any]]:
    """calibrate's ``fit.poorly_determined`` records it held (``action`` "held ..."), by parameter name."""
    poor = (getattr(geo, "fit", None) or {}).get("poorly_determined") or []
    return {str(p["name"]): p for p in poor if str(p.get("action", "")).startswith("held")}


def bounded_poorly_determined(geo: Any, prior: np.ndarray | None) -> np.ndarray | None:
    """``prior`` (precision toward nominal on the geometric parameters, or None) with the joint lengths calibrate
    held as poorly determined kept within their bound instead (precision ``1 / bound²``): held, a pair the data
    determine only together (the UR10 D's d6 and its tool's z) lost its sum and the discovery 0.1086 -> 0.1294 mm
    held out (0.1161 bounded). An angle stays held (:func:`held_poorly_determined`): bounded, a column arm's theta6
    still went 5 bounds off with its tilt effects and compensation.csv turned the wrist by up to 9 deg (free: 6.9
    deg, a7 34 mm, 30 deg); so does a tool's or frame's (its prior is not toward nominal)."""
    poor = _held_poor(geo)
    model = geo.model
    idx = [i for i, (nm, k, u) in enumerate(zip(model.names, model.kinds, model.units, strict=True))
           if nm in poor and k == "kinematic" and u == "mm"]  # fmt: skip
    if not idx:
        return prior
    out = np.zeros(len(model.names)) if prior is None else np.array(prior, dtype=float)
    for i in idx:
        p = poor[model.names[i]]
        out[i] = max(out[i], 1.0 / float(p["bound"]) ** 2)
    return out


def release(prev: Fit | None) -> None:
    """Before a refit: the previous fit's ``(M, k)`` Jacobian and the cross-validation sums kept of it let go (the
    fit evaluates it again if it is read later, :meth:`Fit.release`), so that the refit does not hold them."""
    clear_cache()
    if prev is not None:
        prev.release()


def start(model: ExtendedModel, prev: Fit | None, geo: Any) -> np.ndarray:
    """A refit's start: the previous fit's parameters (the geometric calibration's without one), the previous
    fit's Jacobian let go first (:func:`release`)."""
    release(prev)
    return model.map_from(prev.model.names, prev.theta) if prev is not None else model.map_from(geo.names, geo.x)


def calibration_prior(geo: Any, cfg: Any = None) -> np.ndarray | None:
    """The precision ``(n,)`` of the geometric calibration's prior toward the nominal robot on its joint-level
    parameters (a thin or sparse campaign, :mod:`robocal.identification.thin`: ``strength / width²`` from the
    fit's ``configurations.prior`` record), for the discovery's joint refits to keep it (issue 33 item 3: the same
    regularised geometry under the effects); None without a prior. Frames and tools keep none (their prior is a
    weak bound around the rigid fit, not toward the nominal)."""
    if cfg is not None and cfg.geometry_prior == "none":  # the search without it (``geometry_prior``)
        return None
    rec = ((geo.fit or {}).get("configurations") or {}).get("prior") or {}
    strength = float(rec.get("strength") or 0.0)
    if strength <= 0.0:
        return None
    w = rec["widths"]
    model = geo.model
    joint = np.array([k == "kinematic" for k in model.kinds])
    width = np.where(np.array([u == "mm" for u in model.units]), w["length_mm"], np.deg2rad(w["angle_deg"]))
    return np.where(joint, strength / width**2, 0.0)


__all__ = ["bounded_poorly_determined", "calibration_prior", "held_poorly_determined", "refitter", "release", "start"]
