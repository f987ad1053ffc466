"""What an ISO 9283 run produced: the figures before and after, what "after" is, and the inputs they came from
(returned by :func:`robocal.iso9283.run.run_iso9283`, read by the certificate writer :mod:`.report`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from robocal.iso9283.analysis import IsoResult
from robocal.iso9283.campaign import IsoCampaign
from robocal.iso9283.settings import IsoSettings


@dataclass(frozen=True)
class IsoRun:
    before: IsoResult
    after: IsoResult
    after_kind: str  # "measured" | "predicted"
    iso: IsoCampaign
    settings: IsoSettings
    info: dict[str, Any]


__all__ = ["IsoRun"]
