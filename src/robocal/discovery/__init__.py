"""Model discovery: find what the calibration model is missing, name it, add it, show the gap shrink.

:func:`robocal.discovery.search.discover` runs the search on a campaign; :func:`robocal.workflows.discovery.run`
writes ``discovery.json`` and the report. The library of candidate effects is in
:mod:`robocal.discovery.candidates`.
"""

from robocal.discovery.config import EFFECT_NAMES, DiscoveryConfig

__all__ = ["EFFECT_NAMES", "DiscoveryConfig"]
