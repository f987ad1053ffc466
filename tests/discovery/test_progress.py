"""A long discovery says where it is (console / stage log), and Ctrl-C leaves the last complete output (issue 31
item 3)."""

from __future__ import annotations

import json
import logging

import pytest

from robocal.discovery.search import discover
from robocal.workflows import discovery as wf

from .conftest import make_campaign


def test_discovery_reports_its_steps(tmp_path, caplog):
    camp, robot, _ = make_campaign(tmp_path, "geometric", 3, {"backlash": {"joints": {2: 0.006}}})
    with caplog.at_level(logging.INFO, logger="robocal.discovery"):
        discover(camp, robot)
    lines = [r.getMessage() for r in caplog.records if r.name == "robocal.discovery"]
    text = "\n".join(lines)
    # which step, how far: the search, its library steps, the selection, the layer, the gross-error test
    for phrase in ("the search on", "library F-test search: step 1", "cross-validated selection: step 1",
                   "final held-out check", "gross-error test: every one of the"):  # fmt: skip
        assert phrase in text, (phrase, text)
    assert all(line.startswith("discover [") and " GB] " in line for line in lines)


def _fake_run(monkeypatch, tmp_path, fail_in: str | None):
    """workflows.discovery.run with the discovery itself stubbed (the writing is under test): the product,
    discovery.json and the report written from a fixed summary; ``fail_in`` raises KeyboardInterrupt there."""
    summ = {"named": [], "version": 2}

    class Res:
        accepted = ()
        extra: dict = {}  # noqa: RUF012  (no geometric calibration: nothing to judge the start by)

    monkeypatch.setattr(wf, "robot_of", lambda r: None)
    fake = type("C", (), {"n_rows": 3, "source": "x", "reading_notes": lambda self: [], "u_mm": None})
    monkeypatch.setattr(wf, "campaign_of", lambda *a: fake())
    monkeypatch.setattr(wf, "discover", lambda *a: Res())
    monkeypatch.setattr(wf, "validation_errors", lambda r: None)
    monkeypatch.setattr(wf, "summary", lambda r, v: dict(summ))
    monkeypatch.setattr(wf.DiscoveryConfig, "from_mapping", classmethod(lambda cls, s: wf.DiscoveryConfig()))

    def product(res, s, out):
        (out / "calibration.json").write_text('{"new": true}')
        (out / "compensation.csv").write_text("new\n")
        if fail_in == "product":
            raise KeyboardInterrupt

    def report(res, s, path):
        if fail_in == "report":
            raise KeyboardInterrupt
        path.write_text("<html>new</html>")

    monkeypatch.setattr(wf, "write_product", product)
    monkeypatch.setattr(wf, "write_report", report)
    return wf.run(None, "r", tmp_path / "out")


@pytest.mark.parametrize("where", ["product", "report"])
def test_an_interrupted_run_leaves_the_last_complete_output(monkeypatch, tmp_path, where):
    out = tmp_path / "out"
    out.mkdir()
    old = {"discovery.json": '{"old": 1}', "calibration.json": '{"old": 1}', "compensation.csv": "old\n",
           "report.html": "<html>old</html>"}  # fmt: skip
    for k, v in old.items():
        (out / k).write_text(v)
    with pytest.raises(KeyboardInterrupt):
        _fake_run(monkeypatch, tmp_path, where)
    assert {p.name: p.read_text() for p in out.iterdir()} == old  # untouched, no staging folder left


def test_a_complete_run_replaces_every_output(monkeypatch, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "discovery.json").write_text('{"old": 1}')
    s = _fake_run(monkeypatch, tmp_path, None)
    assert sorted(p.name for p in out.iterdir()) == sorted(s["written"])
    assert json.loads((out / "discovery.json").read_text())["version"] == 2
    assert (out / "report.html").read_text() == "<html>new</html>"
