"""A systematic misfit offered to the search: the rows under its condition measured with their own frame.

When the geometric calibration names a systematic misfit (:mod:`robocal.identification.misfit`: many rows that
stand out together under one condition), the search is offered one candidate per misfit: the tracker-to-base
frame (translation and rotation) steps by a constant for the rows under the condition (``param`` shape, the
signal is 1 under the condition, centred on the calibration rows). If a library effect explains those rows
better, that effect is chosen instead; if the step is chosen it keeps the misfit from biasing the other
effects. It corrects the figures of the fit, never the robot (the condition is not a robot state the controller
knows)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from robocal.data.contract import Campaign
from robocal.discovery.candidates import Candidate
from robocal.identification.misfit import Condition

#: the calibration parameters that step for the rows under the condition
FRAME = ("base_tx", "base_ty", "base_tz", "base_rx", "base_ry", "base_rz")


def misfit_candidates(campaign: Campaign, records: Sequence[dict[str, Any]]) -> list[Candidate]:
    """One candidate per systematic misfit record of the geometric calibration (``fit["systematic_misfit"]``)."""
    cal_rows = campaign.split == "calibration" if np.any(campaign.split == "validation") else slice(None)
    out = []
    for k, rec in enumerate(records):
        cond = Condition.from_dict(rec)
        ind = cond.holds(campaign).astype(float)
        S = (ind - ind[cal_rows].mean())[:, None]
        out.append(
            Candidate(
                f"misfit_{k + 1}", "misfit", None, None,
                cause=f"a systematic misfit of the rows with {rec['condition']} ({rec['n_rows']} calibration rows "
                f"stood out together by {rec['size_mm']} mm): the tracker-to-base frame differs there, or an effect "
                "the library does not hold acts there; it corrects the figures, never the robot",
                signal=f"1 for the rows with {rec['condition']}", shape="param", S=S, params=FRAME,
                signal_names=("in_condition",), extra={"condition": rec["condition"]},
            )
        )  # fmt: skip
    return out


__all__ = ["misfit_candidates"]
