"""Optimizers for identification: one protocol (:class:`Problem` in, :class:`FitResult` out).

Gradient methods: :class:`GaussNewton`, :class:`LevenbergMarquardt` (``robocal.optimizers.solver``),
:class:`Ipopt` (CasADi, exact derivatives). Population methods: :class:`GOA`, :class:`ImprovedGOA` (Guo et al.
2026), :class:`WOA`. Build one from a Hydra ``optimizer`` config with :func:`make_optimizer`; add more with
:func:`register`. The calibration as a Problem: :mod:`robocal.calibration.problem`.
"""

from __future__ import annotations

from robocal.optimizers.goa import GOA, ImprovedGOA
from robocal.optimizers.gradient import GaussNewton, LevenbergMarquardt
from robocal.optimizers.ipopt import Ipopt
from robocal.optimizers.protocol import (
    STATUS_MESSAGES,
    FitResult,
    IterationInfo,
    Optimizer,
    Problem,
    evaluate,
    evaluate_batch,
)
from robocal.optimizers.registry import make_optimizer, pipeline_options, register, registered, unregister
from robocal.optimizers.woa import WOA

__all__ = [
    "GOA",
    "STATUS_MESSAGES",
    "WOA",
    "FitResult",
    "GaussNewton",
    "ImprovedGOA",
    "Ipopt",
    "IterationInfo",
    "LevenbergMarquardt",
    "Optimizer",
    "Problem",
    "evaluate",
    "evaluate_batch",
    "make_optimizer",
    "pipeline_options",
    "register",
    "registered",
    "unregister",
]
