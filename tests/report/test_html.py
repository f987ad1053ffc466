"""The self-contained HTML report builder and the report plots."""

from __future__ import annotations

import base64
import re
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from robocal.report import Report, plots
from robocal.report.html import PNG_SIGNATURE

VOID = {"meta", "img", "br", "hr", "link", "input", "col", "area", "base", "wbr", "source", "track", "embed"}


class _Checker(HTMLParser):
    """Collects tags and attributes; checks that non-void elements are closed in order."""

    def __init__(self) -> None:
        super().__init__()
        self.stack: list[str] = []
        self.errors: list[str] = []
        self.attrs: list[tuple[str, str, str]] = []
        self.tags: list[str] = []
        self.text: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append(tag)
        for k, v in attrs:
            self.attrs.append((tag, k, v or ""))
        if tag not in VOID:
            self.stack.append(tag)

    def handle_endtag(self, tag: str) -> None:
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"unexpected </{tag}>, open: {self.stack[-3:]}")
            return
        self.stack.pop()

    def handle_data(self, data: str) -> None:
        self.text.append(data)


def _parse(doc: str) -> _Checker:
    c = _Checker()
    c.feed(doc)
    c.close()
    assert not c.errors, c.errors[:5]
    assert not c.stack, f"unclosed: {c.stack}"
    return c


def _png_bytes() -> bytes:
    fig = plots.error_histogram([1.0, 2.0, 3.0], [0.1, 0.2])
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=50)
    return buf.getvalue()


def _full_report() -> Report:
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(0)
    rep = Report("Calibration <KR16-2> & friends", subtitle="campaign data/raw/default")
    rep.heading("Fit")
    rep.paragraph("The <b>model</b> fits & the residuals are at the noise floor.\nSecond line.")
    rep.kv({"RMS (mm)": 0.025123456, "iterations": 6, "converged": True, "status": "ok <done>", "none": None})
    rep.heading("Parameters", level=3)
    df = pd.DataFrame({"name": ["a2", "d4"], "value_mm": [0.0123456, -0.5], "stderr_mm": [1e-3, np.nan]})
    rep.table(df, caption="Identified <parameters>")
    rep.table(df.set_index("name"), columns=["value_mm"], float_fmt="{:.2f}")
    rep.table([["a", 1, 2.5], ["b", None, 1e-7]], columns=["x", "n", "v"])
    rep.table([{"p": "theta4", "v": 0.1}, {"p": "beta2", "w": 3}])
    rep.table(np.arange(6.0).reshape(2, 3))
    rep.heading("Figures")
    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    rep.figure(fig, "a pyplot figure <1>")
    rep.figure(plots.error_per_pose(rng.random(5), rng.random(5) / 10), "error per pose")
    rep.figure(_png_bytes(), "")
    rep.heading("Equations", level=3)
    rep.code("dP = J · d_eta   # <code> & more\n  second line")
    rep.note("All parameters identified.")
    rep.note("chi² is outside its band <check>", kind="warn")
    rep.heading("Fit")  # a duplicate title gets its own anchor
    return rep


# ---------------------------------------------------------------------------- the HTML builder


def test_report_with_every_element_renders() -> None:
    doc = _full_report().to_html()
    assert doc.startswith("<!DOCTYPE html>")
    c = _parse(doc)
    for tag in ("h1", "h2", "h3", "nav", "table", "thead", "figure", "figcaption", "img", "pre", "code"):
        assert tag in c.tags, tag
    assert '<div class="caption">' in doc  # above the table, as wide as the page (not a <caption>)
    assert doc.count("<img ") == 3
    assert doc.count('class="note info"') == 1 and doc.count('class="note warn"') == 1
    assert "<style>" in doc and "</style>" in doc


def test_self_contained_no_external_references() -> None:
    doc = _full_report().to_html()
    assert "http://" not in doc and "https://" not in doc
    assert "<script" not in doc.lower()
    assert "@import" not in doc and "url(" not in doc
    c = _parse(doc)
    srcs = [v for _, k, v in c.attrs if k == "src"]
    assert len(srcs) == 3
    for s in srcs:
        assert s.startswith("data:image/png;base64,")
        assert base64.b64decode(s.split(",", 1)[1]).startswith(PNG_SIGNATURE)
    hrefs = [v for _, k, v in c.attrs if k == "href"]
    assert hrefs and all(h.startswith("#") for h in hrefs)


def test_text_is_escaped() -> None:
    doc = _full_report().to_html()
    assert "<b>" not in doc and "&lt;b&gt;model&lt;/b&gt; fits &amp; the residuals" in doc
    assert "Calibration &lt;KR16-2&gt; &amp; friends" in doc  # title and h1
    assert "ok &lt;done&gt;" in doc  # kv value
    assert "Identified &lt;parameters&gt;" in doc  # caption
    assert "&lt;code&gt; &amp; more" in doc  # preformatted
    assert "band &lt;check&gt;" in doc  # note
    assert 'alt="a pyplot figure &lt;1&gt;"' in doc
    assert "fits &amp; the residuals are at the noise floor.<br>Second line." in doc


def test_table_of_contents_links_every_heading() -> None:
    rep = _full_report()
    doc = rep.to_html()
    heads = rep.headings
    assert [h[1] for h in heads] == ["Fit", "Parameters", "Figures", "Equations", "Fit"]
    anchors = [h[2] for h in heads]
    assert len(set(anchors)) == len(anchors)
    toc = doc[doc.index('<nav class="toc"') : doc.index("</nav>")]
    for level, _text, anchor in heads:
        assert f'href="#{anchor}"' in toc
        assert f'<h{level} id="{anchor}">' in doc
    # nesting: level-3 headings sit in a sub-list
    assert toc.count("<ol>") == 3


def test_no_headings_no_toc() -> None:
    doc = Report("plain").paragraph("x").to_html()
    assert "<nav" not in doc
    _parse(doc)


def test_cell_formatting() -> None:
    doc = _full_report().to_html()
    assert ">0.02512<" in doc  # default {:.4g}
    assert ">0.01<" in doc and ">-0.50<" in doc  # float_fmt="{:.2f}", index column kept
    assert ">a2<" in doc and ">value_mm<" in doc
    assert '<td class="num empty">–</td>' in doc and ">nan<" not in doc  # undefined: a dash (issue 23, item 12)
    assert ">1e-07<" in doc
    assert '<td class="num">6</td>' in doc  # ints as they are
    assert "<td>yes</td>" in doc and ">True<" not in doc  # words, not Python's True / False


def test_figure_is_closed_after_rendering() -> None:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    ax.plot([1, 2, 3])
    num = fig.number
    Report("t").figure(fig, "c")
    assert not plt.fignum_exists(num)


def test_save_is_atomic_and_equal_to_to_html(tmp_path: Path) -> None:
    rep = _full_report()
    out = rep.save(tmp_path / "sub" / "report.html")
    assert out.read_text(encoding="utf-8") == rep.to_html()
    assert [p.name for p in out.parent.iterdir()] == ["report.html"]
    # deterministic: the same report renders to the same bytes
    assert _full_report().to_html() == rep.to_html()


def test_chaining_returns_the_report() -> None:
    rep = Report("t")
    assert rep.heading("h").paragraph("p").kv({"a": 1}).code("c").note("n") is rep


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda r: r.heading("x", level=1), "'level'"),
        (lambda r: r.note("x", kind="error"), "'kind'"),
        (lambda r: r.figure(b"GIF89a....", "c"), "'fig_or_png_bytes'"),
        (lambda r: r.figure("not a figure", "c"), "'fig_or_png_bytes'"),
        (lambda r: r.table([[1, 2], [3]]), "'df_or_rows'"),
        (lambda r: r.table([[1, 2]], columns=["a", "b", "c"]), "'df_or_rows'"),
        (lambda r: r.table(np.arange(3.0)), "'df_or_rows'"),
        (lambda r: r.table(42), "'df_or_rows'"),
        (lambda r: r.table(pd.DataFrame({"a": [1]}), columns=["b"]), "'columns'"),
        (lambda r: r.table([[1.0]], float_fmt="{:.2q}"), "'float_fmt'"),
        (lambda r: r.kv([("a", 1)]), "'mapping'"),
    ],
)
def test_bad_input_names_the_argument(call, name: str) -> None:
    with pytest.raises(ValueError, match=re.escape(name)):
        call(Report("t"))


def test_empty_title_is_rejected() -> None:
    with pytest.raises(ValueError, match="'title'"):
        Report("  ")


def test_importing_the_builder_does_not_import_matplotlib() -> None:
    code = "import sys, robocal.report; print('matplotlib' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


# ---------------------------------------------------------------------------- plots

RNG = np.random.default_rng(42)
M, N = 40, 6


def _all_plots() -> dict[str, object]:
    q = RNG.uniform(-2, 2, (M, N))
    return {
        "error_per_pose": plots.error_per_pose(RNG.random(M), RNG.random(M) / 5, [f"c{i:02d}" for i in range(M)]),
        "error_per_pose_many": plots.error_per_pose(RNG.random(200), RNG.random(200) / 5),
        "error_per_pose_vectors": plots.error_per_pose(RNG.normal(size=(M, 3)), RNG.normal(size=(M, 3)) / 5),
        "error_histogram": plots.error_histogram(RNG.random(M), RNG.random(M + 7) / 5),
        "residuals_vs_joints": plots.residuals_vs_joints(q, RNG.normal(0, 0.02, (M, 3))),
        "residuals_vs_joints_scalar": plots.residuals_vs_joints(q[:, :4], RNG.normal(0, 0.02, M), list("ABCD")),
        "convergence": plots.convergence(
            {
                "improved GOA": [list(np.geomspace(1, 0.01, 50)), list(np.geomspace(2, 0.02, 30))],
                "GOA": np.geomspace(1, 0.05, 80),
                "WOA": [3.0, 2.0, 1.0, 0.9],
            }
        ),
        "time_series": plots.time_series(
            np.arange(0, 180, 30.0), {"T_j1_C": RNG.random(6) + 24, "T_j2_C": [24, 25, np.nan, 27, 28, 28]}, "°C"
        ),
        "bar_table": plots.bar_table(
            ["uncompensated", "traditional", "proposed"],
            {"mean (mm)": [0.9076, 0.4418, 0.3467], "max (mm)": [1.2652, 0.8957, 0.7849]},
            "position error (mm)",
        ),
        "parameter_errors": plots.parameter_errors(
            ["a2", "d4", "theta4", "beta2"], RNG.normal(size=4), [0.01, 0.02, np.nan, 0.005], truth=RNG.normal(size=4)
        ),
        "parameter_errors_no_truth": plots.parameter_errors(["a2"], [0.1], [0.01]),
    }


def test_every_plot_returns_a_figure_and_embeds() -> None:
    from matplotlib.figure import Figure

    figs = _all_plots()
    rep = Report("plots")
    for name, fig in figs.items():
        assert isinstance(fig, Figure), name
        assert fig.axes, name
        rep.figure(fig, name)
    doc = rep.to_html()
    assert doc.count("data:image/png;base64,") == len(figs)


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda: plots.error_per_pose(np.ones(5), np.ones(4)), "'after_mm'"),
        (lambda: plots.error_per_pose(np.ones((5, 2)), np.ones(5)), "'before_mm'"),
        (lambda: plots.error_per_pose([], []), "'before_mm'"),
        (lambda: plots.error_per_pose(np.ones(3), np.ones(3), ["a", "b"]), "'labels'"),
        (lambda: plots.error_histogram([1.0, np.nan], [1.0]), "'before_mm'"),
        (lambda: plots.error_histogram([1.0], np.ones((2, 2))), "'after_mm'"),
        (lambda: plots.error_histogram([1.0], [1.0], bins=0), "'bins'"),
        (lambda: plots.residuals_vs_joints(np.ones(6), np.ones(6)), "'q_rad'"),
        (lambda: plots.residuals_vs_joints(np.ones((5, 6)), np.ones((4, 3))), "'residual_mm'"),
        (lambda: plots.residuals_vs_joints(np.ones((5, 6)), np.ones((5, 2))), "'residual_mm'"),
        (lambda: plots.residuals_vs_joints(np.ones((5, 2)), np.ones(5), ["a"]), "'joint_names'"),
        (lambda: plots.convergence({}), "'histories'"),
        (lambda: plots.convergence({"GOA": []}), "histories['GOA']"),
        (lambda: plots.convergence({"GOA": [[1.0, 2.0], []]}), "histories['GOA']"),
        (lambda: plots.convergence({"GOA": [1.0, np.nan]}), "histories['GOA']"),
        (lambda: plots.time_series(np.ones((3, 1)), {"a": [1, 2, 3]}, "y"), "'t_min'"),
        (lambda: plots.time_series([0, 1, 2], {"T_j1_C": [1, 2]}, "y"), "series['T_j1_C']"),
        (lambda: plots.time_series([0, 1, 2], {}, "y"), "'series'"),
        (lambda: plots.bar_table(["a", "b"], {"mean": [1.0]}, "y"), "values['mean']"),
        (lambda: plots.bar_table([], {"mean": [1.0]}, "y"), "'labels'"),
        (lambda: plots.parameter_errors(["a", "b"], [1.0, 2.0], [0.1]), "'stderr'"),
        (lambda: plots.parameter_errors(["a", "b"], [1.0, 2.0], [0.1, -0.1]), "'stderr'"),
        (lambda: plots.parameter_errors(["a", "b"], [1.0], [0.1, 0.1]), "'estimate'"),
        (lambda: plots.parameter_errors(["a", "b"], [1.0, 2.0], [0.1, 0.1], truth=[1.0]), "'truth'"),
    ],
)
def test_plot_inputs_are_validated(call, name: str) -> None:
    with pytest.raises(ValueError, match=re.escape(name)):
        call()


@pytest.mark.parametrize("suffix", [".png", ".svg"])
def test_save_figure_by_suffix_and_deterministic(tmp_path: Path, suffix: str) -> None:
    def build():
        return plots.bar_table(["a", "b"], {"x": [1.0, 2.0]}, "y")

    # the same figure built twice gives the same file (no dates, versions or random ids): DVC-friendly
    p1 = plots.save_figure(build(), tmp_path / f"one{suffix}")
    p2 = plots.save_figure(build(), tmp_path / "deeper" / f"two{suffix}")
    data = p1.read_bytes()
    if suffix == ".png":
        assert data.startswith(PNG_SIGNATURE)
    else:
        assert b"<svg" in data[:2000]
    assert data == p2.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["deeper", f"one{suffix}"]


def test_save_figure_rejects_other_suffixes(tmp_path: Path) -> None:
    fig = plots.bar_table(["a"], {"x": [1.0]}, "y")
    with pytest.raises(ValueError, match="'path'"):
        plots.save_figure(fig, tmp_path / "x.pdf")
    assert not any(tmp_path.iterdir())


def test_lists_arrays_and_mappings_are_written_as_text_not_reprs():
    from robocal.report.html import Report

    rep = Report("t").kv(
        {"tool (mm)": np.array([35.0, -20.0, 120.0]), "tools": [[1.5, 2.0, 3.0]], "map": {"a": 1}, "flag": True}
    )
    body = rep.to_html().split("<body", 1)[-1]
    assert "35, -20, 120" in body and "(1.5, 2, 3)" in body and "a: 1" in body
    assert "array(" not in body and "[35" not in body and "{&#x27;" not in body
