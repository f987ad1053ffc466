"""The service's settings (:class:`ServiceConfig`, checked by :meth:`ServiceConfig.from_mapping`); its safety
settings are the one safety policy (:data:`SafetyConfig`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from robocal.compensation.correct import SolverConfig
from robocal.compensation.safety import SafetyPolicy
from robocal.config import parse, setting

#: the service's safety settings are the one safety policy (:class:`robocal.compensation.safety.SafetyPolicy`)
SafetyConfig = SafetyPolicy


@dataclass(frozen=True)
class ServiceConfig:
    """Service settings; :meth:`from_mapping` checks names and values. The shared ``token`` is no setting (never
    in a config file): it comes from the environment or a token file, as the ``token`` argument."""

    max_targets: int = setting(100_000, ge=1)
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    solver: SolverConfig = field(default_factory=SolverConfig)
    #: a robot on external axes (a track, a column): whether a correction may move them (a request's
    #: ``move_external`` overrides it); by default only the arm is corrected
    move_external: bool = False
    token: str | None = setting(None, settable=False)

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any] | None, token: str | None = None) -> ServiceConfig:
        return replace(parse(cls, cfg, "serve"), token=token)


#: the keys of the ``serve`` section that are the service's (the rest are the transport's: ServerConfig)
SERVICE_KEYS = ("max_targets", "safety", "solver", "move_external")
