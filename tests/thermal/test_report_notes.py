"""The thermal report's warnings carry one "Warning:" label (the note adds it; issue 30 item 10)."""

from __future__ import annotations

from robocal.report.html import Report
from robocal.thermal.report import compensation_section


def test_compensation_warnings_are_labelled_once() -> None:
    comp = {
        "warning": "4 of 15 targets of compensation.csv are not ok (refused: 4); see the status and reason columns",
        "t_min": 60.0,
        "n_targets": 15,
        "n_applied": 11,
        "status_counts": {"ok": 11, "refused": 4},
        "max_correction_deg": 0.1,
        "limits": {},
        "flagged": [],
    }
    ext = {"warning": "the thermal model extrapolates: 3 of 40 rows", "margin_C": 1.0, "fitted_range_C": {}}
    html = compensation_section(Report("t"), {"compensation": comp, "extrapolation": ext}).to_html()
    assert "Warning: Warning" not in html.replace("</span>", "")
    assert html.count('<span class="note-kind">Warning:</span>') == 2
    assert '<span class="note-kind">Warning:</span>4 of 15 targets' in html
