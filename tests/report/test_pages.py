"""Every report page the commands write reads clean (issue 23, item 12): no Python repr, no nan / True / False /
None as a value, no token or line wider than the page, and (where Chromium is installed) nothing wider than a
1000 px window in headless Chromium. The pipeline's pages are checked in tests/pipeline/test_repro.py."""

from __future__ import annotations

from pathlib import Path

import pytest

from robocal.cli import main
from robocal.report.html import Report, layout_problems, page_problems


def test_the_page_check_finds_what_a_reader_must_not_see() -> None:
    """The checks themselves: each catches its case, a clean page passes."""
    assert page_problems(Report("clean").kv({"converged": True, "x": float("nan"), "n": None}).to_html()) == []
    bad = (
        Report("bad")
        .code("PlanConfig(n_poses=30, criterion='D')")
        .paragraph("id np.str_('B0001') unknown; " + "x" * 70)
        .paragraph("flag False")
        .to_html()
    )
    found = "\n".join(page_problems(bad))
    assert "PlanConfig(n_poses" in found and "np.str_(" in found
    assert "'False' in the text" in found and "unbreakable token of 70" in found
    old_cell = '<table><tbody><tr><td>True</td><td class="num empty">nan</td></tr></tbody></table>'
    assert len([p for p in page_problems(f"<body>{old_cell}</body>") if "raw value in a cell" in p]) == 2


def _check(pages: list[Path]) -> None:
    for page in pages:
        assert page.is_file(), page
        problems = page_problems(page.read_text(encoding="utf-8"))
        assert not problems, f"{page}:\n" + "\n".join(problems[:10])
    layout = layout_problems(pages)
    if layout is not None:  # headless Chromium installed: nothing wider than a 1000 px window
        wide = {p: v for p, v in layout.items() if v}
        assert not wide, wide


@pytest.mark.e2e  # every command page rendered (9 s): make e2e (CI), outside make test's 5 minutes
def test_the_commands_pages_read_clean(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    camp, fleet = tmp_path / "camp", tmp_path / "fleet"
    args = ["simulate", "geometric", "n_poses=25", "n_validation_poses=8", "--out", str(camp), "--seed", "1"]
    assert main(args) == 0
    assert main(["calibrate", str(camp), "--robot", "kr16_2", "--out", str(tmp_path / "cal")]) == 0
    plan = ["plan", "--robot", "kr16_2", "--n", "15", "--out", str(tmp_path / "plan"), "n_candidates=2000"]
    assert main([*plan, "region.n=60", "max_exchanges=200"]) == 0
    assert main(["fleet", "--simulate", "2", "--campaigns", "2", "--out", str(fleet), "twin.n_poses=30"]) == 0
    out = tmp_path / "fleet-out"
    assert main(["fleet", str(fleet), "--out", str(out), "--no-tracking", "--no-progress"]) == 0
    heavy = tmp_path / "heavy"
    assert main(["simulate", "heavy_load", "n_poses=30", "--out", str(heavy), "--seed", "0"]) == 0
    assert main(["compliance", str(heavy), "--robot", "sr210", "--out", str(tmp_path / "comp")]) == 0
    capsys.readouterr()
    pages = ["cal", "plan", "comp"]
    _check([tmp_path / p / "report.html" for p in pages] + [out / "report.html"])
