"""Reports: a self-contained HTML builder (:mod:`robocal.report.html`) and plots (:mod:`robocal.report.plots`).

``from robocal.report import Report`` is light (no matplotlib); import :mod:`robocal.report.plots` for the
figures (it selects matplotlib's Agg backend).
"""

from robocal.report.html import Report

__all__ = ["Report"]
