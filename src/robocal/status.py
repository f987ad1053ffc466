"""The status words robocal writes, one vocabulary per level, as str-valued enums (a member *is* its string:
``StageStatus.OK == "ok"``, and JSON, CSV files and MLflow tags hold the plain word).

* :class:`StageStatus`: a pipeline stage's outcome (``reports/metrics/<stage>.json``, ``result.json``, the
  ``robocal.status`` tag of its MLflow run).
* :class:`CampaignStatus`: one campaign's calibration. The geometric workflow writes ``ok`` / ``warning`` /
  ``failed`` (``summary.json``, by :func:`robocal.identification.acceptance.judge`: warnings, problems); the
  fleet writes ``ok`` / ``rejected`` / ``error`` with ``accepted`` (its ``summary.json``, ``fleet.json``, MLflow):
  ``rejected`` is the fleet's word for a calibration with problems (``failed`` in the workflow) and ``error``
  a campaign that could not be computed. The two words for one meaning are kept because the fleet's files and
  tags are read by name; new code uses the members, not the strings.
* :class:`TargetStatus`: one corrected target (service reply, program filter, controller CSV), decided by the
  one safety policy :class:`robocal.compensation.safety.SafetyPolicy`.

Importing it reads and writes nothing.
"""

from __future__ import annotations

from enum import StrEnum

__all__ = ["CampaignStatus", "StageStatus", "TargetStatus"]


class StageStatus(StrEnum):
    """A pipeline stage: computed and usable, usable with care, unusable, or nothing to do."""

    OK = "ok"
    WARNING = "warning"
    FAILED = "failed"
    SKIPPED = "skipped"


class CampaignStatus(StrEnum):
    """One campaign's calibration (module doc: the workflow's and the fleet's words)."""

    OK = "ok"
    WARNING = "warning"
    FAILED = "failed"
    REJECTED = "rejected"
    ERROR = "error"


class TargetStatus(StrEnum):
    """One corrected target: corrected, corrected but flagged (a reason is given), or not corrected."""

    OK = "ok"
    FLAGGED = "flagged"
    REFUSED = "refused"
