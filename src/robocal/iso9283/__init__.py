"""ISO 9283:1998 pose characteristics: the formulas (:mod:`.characteristics`), a test campaign's ISO columns
(:mod:`.campaign`), the evaluation (:mod:`.analysis`), the test program (:mod:`.program`), the twin's test
(:mod:`.twin`) and the certificate (:mod:`.report`). ``robocal iso9283`` runs
:func:`robocal.iso9283.run.run_iso9283`."""

from robocal.iso9283.analysis import IsoResult, IsoTest, PoseResult, evaluate
from robocal.iso9283.settings import IsoSettings

__all__ = ["IsoResult", "IsoSettings", "IsoTest", "PoseResult", "evaluate"]
