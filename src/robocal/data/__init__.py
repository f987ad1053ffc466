"""The data door: :func:`read_campaign` reads a campaign in the data contract into a :class:`Campaign`."""

from robocal.data.campaign import Campaign, SplitConfig
from robocal.data.contract import read_campaign

__all__ = ["Campaign", "SplitConfig", "read_campaign"]
