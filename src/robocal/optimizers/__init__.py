"""Optimizers for identification: one protocol (:class:`Problem` in, :class:`OptimizeResult` out).

Population methods: :class:`GOA`, :class:`ImprovedGOA` (Guo et al. 2026), :class:`WOA`. Build one from a
Hydra ``optimizer`` config with :func:`make_optimizer`; add more with :func:`register`.
"""

from __future__ import annotations

from robocal.optimizers.goa import GOA, ImprovedGOA
from robocal.optimizers.protocol import (
    STATUS_MESSAGES,
    IterationInfo,
    Optimizer,
    OptimizeResult,
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
    "ImprovedGOA",
    "IterationInfo",
    "OptimizeResult",
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
