"""One status vocabulary per level (robocal.status): members are the words the files hold."""

from __future__ import annotations

import json

import numpy as np

from robocal.compensation.safety import STATUSES, SafetyPolicy
from robocal.pipeline import STATUS_OK, STATUS_SKIPPED
from robocal.status import CampaignStatus, StageStatus, TargetStatus
from robocal.workflows.geometric import status_of


def test_members_are_their_words_in_every_format():
    assert [str(s) for s in StageStatus] == ["ok", "warning", "failed", "skipped"]
    assert [str(s) for s in TargetStatus] == ["ok", "flagged", "refused"] == list(STATUSES)
    assert json.dumps({"status": CampaignStatus.REJECTED, TargetStatus.OK: 1}) == '{"status": "rejected", "ok": 1}'
    assert np.array([TargetStatus.REFUSED]).dtype.kind == "U"  # numpy tables hold plain strings
    assert (STATUS_OK, STATUS_SKIPPED) == (StageStatus.OK, StageStatus.SKIPPED)


def test_writers_use_the_members():
    assert status_of({"problems": ["x"]}) is CampaignStatus.FAILED
    assert status_of({"warnings": ["x"]}) is CampaignStatus.WARNING and status_of({}) is CampaignStatus.OK
    limits = np.deg2rad(np.array([[-170.0, 170.0]] * 2))
    q = np.zeros((2, 2))
    q[1, 0] = np.deg2rad(175.0)  # outside the joint limits: refused by default
    z = np.zeros(2)
    status, _ = SafetyPolicy().judge(np.ones(2, bool), z, z, z, z, q, q, limits, ("a1", "a2"))
    assert status == [TargetStatus.OK, TargetStatus.REFUSED] and all(isinstance(s, TargetStatus) for s in status)
