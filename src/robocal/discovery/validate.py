"""Validation of a discovery: the geometric and the discovered model on the campaign's held-out rows."""

from __future__ import annotations

from typing import Any

import numpy as np

from robocal.discovery.model import Fit
from robocal.discovery.search import DiscoveryResult
from robocal.identification.calibrate import validate_rows
from robocal.identification.model import FitData
from robocal.kinematics.chain import fk


def _validate_fit(res: DiscoveryResult, fit: Fit) -> dict[str, Any]:
    """One model's errors on the validation rows, through :func:`validate_rows` (the tool and station handling
    of ``calibrate``'s validation): joint-level effects enter the joint angles exactly, parameter drifts
    (thermal, drift) to first order at the tool, as in the fit."""
    camp = res.campaign
    vrows = np.flatnonzero(camp.split == "validation")
    val = camp.subset(vrows)
    model = fit.model
    base = model.base
    x = fit.theta[: model.nb]
    q = val.q + model.joint_offsets(fit.theta, vrows, 0)
    base_T_flange = fk(base.chain, q, x[: base.chain.n_params])
    stations = {s: base.base_transform(x, k) for k, s in enumerate(base.station_names)}
    tools = {t: base.tools(x)[k] for k, t in enumerate(base.target_names)}
    tool_R = None
    if base.orientation:
        tool_R = {t: R for t, R in zip(base.target_names, base.tool_rotations(x), strict=True)}
    dp = None
    params = [(a, sl) for a, sl in zip(model.accepted, model.slices, strict=True) if a.cand.shape == "param"]
    if params:
        # the drift's first-order displacement; a target or station the fit never saw uses the first one's
        ti = np.array([base.target_names.index(t) if t in base.target_names else 0 for t in val.target])
        st_names = [] if val.station is None else list(val.station)
        si = np.array([base.station_names.index(s) if s in base.station_names else 0 for s in st_names], dtype=int)
        _, Jb = base.residuals_and_jacobian(x, FitData(q, val.p_mm, ti, None, si))
        Jx = Jb.reshape(val.n_rows, 3, model.nb)
        dp = np.zeros((val.n_rows, 3))
        for a, sl in params:
            idx = [base.index(p) for p in a.params]
            cols = (Jx[:, :, idx][:, :, :, None] * a.cand.S[vrows][:, None, None, :]).reshape(val.n_rows, 3, -1)
            dp += np.einsum("mij,j->mi", cols, fit.theta[sl])
    v = validate_rows(val, base_T_flange, stations, tools, tool_R, dp_mm=dp)
    return {k: val_ for k, val_ in v.items() if k not in ("errors_mm", "kept_rows")}


def validation_errors(res: DiscoveryResult) -> dict[str, Any] | None:
    """The geometric calibration, the discovered (parametric extended) model and the final model on the
    campaign's validation rows, with the same rows and the same tool and station handling as ``calibrate``
    (``{"geometric": {...}, "discovered": {...}, "final": {...}}``, mm / deg).

    ``geometric`` is ``robocal calibrate``'s own result on the same campaign (the discovery's first step: same
    rows, same noise, same gross errors), so the two commands can be read one against the other. ``final`` is
    the model the service applies: the discovered one with the residual layer on top when the cross-validated
    selection accepted it (``final["layer"]``: ``"accepted"`` or ``"none"``)."""
    from robocal.identification.calibrate import validate

    camp = res.campaign
    if not np.any(camp.split == "validation"):
        return None
    geo = res.extra.get("geometric_calibration")
    if geo is not None:
        g = {k: v for k, v in validate(geo, camp).items() if k not in ("errors_mm", "kept_rows")}
    else:
        g = _validate_fit(res, res.geometric)
    parametric = res.extra.get("parametric", res.final)
    disc = _validate_fit(res, parametric)
    if parametric is res.final:
        return {"geometric": g, "discovered": disc, "final": {**disc, "layer": "none"}}
    return {"geometric": g, "discovered": disc, "final": {**_validate_fit(res, res.final), "layer": "accepted"}}


__all__ = ["validation_errors"]
