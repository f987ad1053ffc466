"""Progress of a long discovery: which step, how far, how long so far (issue 31 item 3).

Lines go to the ``robocal.discovery`` logger at INFO: under the pipeline's Hydra logging they are in the stage's
log on the console; run from ``robocal discover`` (or a script) with no logging configured they go to stderr.
They are never written into an output file (timings are not tracked outputs). Within a loop, :class:`Ticker`
says how far at most every few seconds, so a small campaign prints a handful of lines and a large one shows
that it moves.
"""

from __future__ import annotations

import logging
import sys
import time

log = logging.getLogger("robocal.discovery")
_T0 = [time.perf_counter()]
#: seconds between two lines of one loop
EVERY_S = 5.0


def _ready() -> None:
    if log.level == logging.NOTSET:
        log.setLevel(logging.INFO)
    if not log.hasHandlers():  # nobody configured logging: the console
        h = logging.StreamHandler(sys.stderr)
        h.setFormatter(logging.Formatter("%(message)s"))
        log.addHandler(h)


def start(what: str) -> None:
    """A discovery starts: the clock of its progress lines."""
    _T0[0] = time.perf_counter()
    note(what)


def note(what: str) -> None:
    """One progress line: ``discover [  12.3 s, 0.41 GB] <what>`` (time so far, the process's peak memory)."""
    _ready()
    log.info("discover [%7.1f s, %5.2f GB] %s", time.perf_counter() - _T0[0], _peak_gb(), what)


def _peak_gb() -> float:
    try:
        import resource

        return float(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) / 1024**2  # KB on Linux
    except (ImportError, OSError):  # not on this platform
        return float("nan")


class Ticker:
    """How far a loop of ``total`` items has come, at most every :data:`EVERY_S` seconds (and its first item)."""

    def __init__(self, what: str, total: int) -> None:
        self.what, self.total = what, total
        self.last = -float("inf")

    def tick(self, done: int) -> None:
        now = time.perf_counter()
        if now - self.last >= EVERY_S:
            self.last = now
            note(f"{self.what}: {done}/{self.total}")


__all__ = ["EVERY_S", "Ticker", "log", "note", "start"]
