"""What the steps of one discovery search share: the campaign rows it fits, how it refits, and the model so far.

:func:`robocal.discovery.search._search` builds one :class:`DiscoveryState` after the geometric fit; the library's
F-test search, the cross-validated selection (:func:`robocal.discovery.grow.grow`), the proposed equations, the
held-out checks and the residual layer (:func:`robocal.discovery.grow.finish`) each read it and advance its fit,
its accepted effects, its steps and its cross-validation record in place.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from robocal.data.contract import Campaign
from robocal.discovery.config import DiscoveryConfig
from robocal.discovery.model import Accepted, Fit
from robocal.discovery.scoring import Step
from robocal.discovery.session_cv import Sessions
from robocal.identification.model import FitData
from robocal.robot import RobotDescription

#: a joint refit of the model with these effects, started from the previous fit (None: the geometric calibration)
Refit = Callable[[list[Accepted], Fit | None], Fit]


@dataclass
class DiscoveryState:
    """One search's shared state. Fixed for the search: the ``campaign`` and ``robot``, the settings ``cfg``, the
    campaign rows fitted (``rows``; their fit data ``data``), the pose of each whitened residual (``groups``, the
    cross-validation's folds), the joint ``refit`` of the whole model and, for a campaign of several sessions,
    their leave-one-session-out ``sessions`` (None: one session, or no cross-validation). Advanced by the steps:
    the current ``fit``, the ``accepted`` effects, the ``steps`` reported and the cross-validation ``record``
    (the selection's candidates and steps, what the held-out checks dropped, the final contributions)."""

    campaign: Campaign
    robot: RobotDescription
    cfg: DiscoveryConfig
    rows: np.ndarray
    data: FitData
    groups: np.ndarray
    refit: Refit
    fit: Fit
    accepted: list[Accepted] = field(default_factory=list)
    steps: list[Step] = field(default_factory=list)
    record: dict[str, Any] = field(default_factory=dict)
    sessions: Sessions | None = None
