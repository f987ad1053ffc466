"""A tiny builder for self-contained HTML reports.

The output is one file that opens offline in any browser: CSS inline, figures embedded as base64 PNG
``data:`` URIs, no script, no external URL. Every piece of text is HTML-escaped.

Example::

    rep = Report("Geometric calibration")
    rep.heading("Fit")
    rep.kv({"RMS (mm)": 0.0251, "iterations": 6})
    rep.table(df, caption="Identified parameters")
    rep.figure(fig, "Error per pose")          # a matplotlib Figure (closed after rendering) or PNG bytes
    rep.save("reports/geometric/report.html")  # atomic

Elements are added in order; a table of contents linking every heading is put at the top.
"""

from __future__ import annotations

import base64
import html
import io
import math
import re
import sys
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Self

import numpy as np

from robocal.io import is_reproducible, is_timing, write_text

__all__ = ["PNG_SIGNATURE", "Report", "words"]

#: The first eight bytes of every PNG file.
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

_NOTE_KINDS = ("info", "warn")
_HEADING_LEVELS = (2, 3, 4)

_CSS = """
:root { --fg: #1d2430; --muted: #5b6575; --line: #d5dae1; --stripe: #f5f7fa; --accent: #1f5fa8;
        --info-bg: #eef4fb; --info-line: #1f5fa8; --warn-bg: #fff6e5; --warn-line: #c77700; --code-bg: #f3f4f6; }
* { box-sizing: border-box; }
html { font-size: 15px; }
body { margin: 0; color: var(--fg); background: #fff; line-height: 1.5;
       font-family: -apple-system, "Segoe UI", Roboto, "Helvetica Neue", Arial, "Noto Sans", sans-serif; }
main { max-width: 1080px; margin: 0 auto; padding: 1.5rem 1.5rem 4rem; }
header { border-bottom: 3px solid var(--accent); margin-bottom: 1.2rem; padding-bottom: .4rem; }
h1 { font-size: 1.7rem; margin: .2rem 0 .2rem; }
.subtitle { color: var(--muted); margin: 0; }
h2 { font-size: 1.3rem; margin: 2.2rem 0 .6rem; padding-bottom: .2rem; border-bottom: 1px solid var(--line); }
h3 { font-size: 1.1rem; margin: 1.6rem 0 .5rem; }
h4 { font-size: 1rem; margin: 1.2rem 0 .4rem; color: var(--muted); }
h2 a.anchor, h3 a.anchor, h4 a.anchor { color: var(--line); text-decoration: none; margin-left: .4rem;
       font-weight: normal; }
h2:hover a.anchor, h3:hover a.anchor, h4:hover a.anchor { color: var(--muted); }
p { margin: .5rem 0 .8rem; }
p, .note, .caption, figcaption, .subtitle { overflow-wrap: break-word; }  /* a long path breaks, not the page */
nav.toc { background: var(--stripe); border: 1px solid var(--line); border-radius: 4px; padding: .6rem 1.2rem;
          margin: 0 0 1.5rem; }
nav.toc .toc-title { font-weight: 600; margin: 0 0 .3rem; }
nav.toc ol { margin: 0; padding-left: 1.3rem; }
nav.toc a { color: var(--accent); text-decoration: none; }
nav.toc a:hover { text-decoration: underline; }
.table-wrap { overflow-x: auto; margin: .6rem 0 1.2rem; }
table { border-collapse: collapse; font-size: .92rem; font-variant-numeric: tabular-nums; }
.caption { text-align: left; color: var(--muted); padding: 0 0 .3rem; font-size: .9rem; max-width: 60rem; }
th, td { border-bottom: 1px solid var(--line); padding: .28rem .7rem; vertical-align: top; text-align: left; }
thead th { border-bottom: 2px solid var(--fg); font-weight: 600; vertical-align: bottom; }
tbody tr:nth-child(even) { background: var(--stripe); }
td.num { text-align: right; font-family: ui-monospace, "SFMono-Regular", Menlo, Consolas, monospace; }
td.empty { color: var(--muted); }
table.kv th { font-weight: 600; color: var(--muted); white-space: nowrap; }
figure { margin: 1rem 0 1.6rem; text-align: center; }
figure img { max-width: 100%; height: auto; border: 1px solid var(--line); }
figcaption { color: var(--muted); font-size: .9rem; margin-top: .3rem; }
pre { background: var(--code-bg); border: 1px solid var(--line); border-radius: 4px; padding: .7rem 1rem;
      overflow-x: auto; font-size: .88rem; line-height: 1.4; }
code { font-family: ui-monospace, "SFMono-Regular", Menlo, Consolas, monospace; }
.note { border-left: 4px solid var(--info-line); background: var(--info-bg); padding: .5rem .9rem;
        margin: .8rem 0 1rem; border-radius: 0 4px 4px 0; }
.note.warn { border-left-color: var(--warn-line); background: var(--warn-bg); }
.note .note-kind { font-weight: 600; margin-right: .4rem; }
footer { color: var(--muted); font-size: .8rem; margin-top: 3rem; border-top: 1px solid var(--line);
         padding-top: .5rem; }
@media print { nav.toc { display: none; } main { max-width: none; } figure, table { page-break-inside: avoid; } }
"""


@dataclass(frozen=True)
class _Heading:
    level: int
    text: str
    anchor: str


def _esc(text: object) -> str:
    return html.escape(str(text), quote=True)


def _slug(text: str) -> str:
    s = re.sub(r"[^\w]+", "-", text.lower()).strip("-")
    return f"sec-{s}" if s else "sec"


def _format_cell(v: object, float_fmt: str) -> tuple[str, str]:
    """(escaped text, css class) of one table cell."""
    if v is None:  # no value: a dash, not a blank cell that reads as missing output
        return "–", "empty"
    if isinstance(v, bool | np.bool_):  # words, not Python's True / False
        return ("yes" if v else "no"), ""
    if isinstance(v, int | np.integer):
        return _esc(int(v)), "num"
    if isinstance(v, float | np.floating):
        f = float(v)
        if math.isnan(f):  # undefined: a dash, not Python's nan
            return "–", "num empty"
        if math.isinf(f):
            return ("∞" if f > 0 else "−∞"), "num"
        return _esc(float_fmt.format(f)), "num"
    if isinstance(v, list | tuple | np.ndarray | Mapping):  # never a Python / numpy repr on the page
        return _esc(_plain(v, float_fmt)), ""
    return _esc(v), ""


def _plain(v: object, float_fmt: str) -> str:
    """Readable text of a (nested) list, array or mapping: ``1, 2, 3``; ``(1, 2); (3, 4)``; ``a: 1, b: 2``."""
    if isinstance(v, np.ndarray):
        v = v.tolist()
    if isinstance(v, Mapping):
        return ", ".join(f"{k}: {_plain(x, float_fmt)}" for k, x in v.items())
    if isinstance(v, list | tuple):
        if any(isinstance(x, list | tuple | np.ndarray | Mapping) for x in v):
            return "; ".join(f"({_plain(x, float_fmt)})" for x in v)
        return ", ".join(_plain(x, float_fmt) for x in v)
    if isinstance(v, bool | np.bool_):
        return "yes" if v else "no"
    if isinstance(v, float | np.floating):
        return "–" if math.isnan(float(v)) else float_fmt.format(float(v))
    if v is None:
        return "–"
    return str(v)


class Report:
    """A self-contained HTML report, built element by element.

    Parameters
    ----------
    title : str
        Shown as the page title and the top ``<h1>``.
    subtitle : str, optional
        A line under the title (e.g. the data set or the run).

    Every adding method returns the report, so calls can be chained.
    """

    def __init__(self, title: str, subtitle: str | None = None) -> None:
        if not isinstance(title, str) or not title.strip():
            raise ValueError(f"The 'title' parameter of Report must be a non-empty str. Got {title!r} instead.")
        self.title = title
        self.subtitle = subtitle
        self._parts: list[str | _Heading] = []
        self._anchors: set[str] = set()

    # ------------------------------------------------------------------ elements

    def heading(self, text: str, level: int = 2) -> Self:
        """A section heading (``level`` 2, 3 or 4; level 1 is the title), listed in the table of contents."""
        if level not in _HEADING_LEVELS:
            raise ValueError(
                f"The 'level' parameter of Report.heading must be one of {_HEADING_LEVELS}. Got {level!r} instead."
            )
        base = _slug(str(text))
        anchor, k = base, 2
        while anchor in self._anchors:
            anchor, k = f"{base}-{k}", k + 1
        self._anchors.add(anchor)
        self._parts.append(_Heading(level, str(text), anchor))
        return self

    def paragraph(self, text: str) -> Self:
        """A paragraph of plain text (escaped; line breaks are kept)."""
        self._parts.append(f"<p>{_esc(text).replace(chr(10), '<br>')}</p>")
        return self

    def kv(self, mapping: Mapping[str, Any], caption: str | None = None, float_fmt: str = "{:.4g}") -> Self:
        """A two-column key / value table (numbers formatted with ``float_fmt``)."""
        if not isinstance(mapping, Mapping):
            raise ValueError(
                f"The 'mapping' parameter of Report.kv must be a mapping. Got {type(mapping).__name__} instead."
            )
        _check_float_fmt(float_fmt, "Report.kv")
        rows = []
        for k, v in mapping.items():
            if is_reproducible() and is_timing(k):  # same config, same bytes: timings are not written
                continue
            text, cls = _format_cell(v, float_fmt)
            td = f'<td class="{cls}">' if cls else "<td>"
            rows.append(f'<tr><th scope="row">{_esc(k)}</th>{td}{text}</td></tr>')
        # the caption above the table, as wide as the page (a <caption> is as narrow as its table: one word a line)
        cap = f'<div class="caption">{_esc(caption)}</div>' if caption else ""
        self._parts.append(
            f'<div class="table-wrap">{cap}<table class="kv"><tbody>{"".join(rows)}</tbody></table></div>'
        )
        return self

    def table(
        self,
        df_or_rows: Any,
        columns: Sequence[str] | None = None,
        caption: str | None = None,
        float_fmt: str = "{:.4g}",
    ) -> Self:
        """A table from a pandas DataFrame, a 2-D array, a list of rows or a list of dicts.

        Parameters
        ----------
        df_or_rows : DataFrame, ndarray of shape (r, c), sequence of sequences or sequence of mappings
            A DataFrame keeps its columns (and its index when that is not the default range index);
            dict rows give the columns in first-seen key order (missing keys are blank).
        columns : sequence of str, optional
            Header. For a DataFrame, selects and orders its columns; for rows, names them (every row must
            then have ``len(columns)`` cells). Without it plain rows get no header.
        caption : str, optional
        float_fmt : str
            ``str.format`` pattern for floats; ints, strings and None (blank) are shown as they are.
        """
        _check_float_fmt(float_fmt, "Report.table")
        header, rows = _table_rows(df_or_rows, columns)
        cap = f'<div class="caption">{_esc(caption)}</div>' if caption else ""
        head = ""
        if header is not None:
            head = "<thead><tr>" + "".join(f'<th scope="col">{_esc(h)}</th>' for h in header) + "</tr></thead>"
        body = []
        for row in rows:
            cells = []
            for v in row:
                text, cls = _format_cell(v, float_fmt)
                cells.append(f'<td class="{cls}">{text}</td>' if cls else f"<td>{text}</td>")
            body.append("<tr>" + "".join(cells) + "</tr>")
        self._parts.append(f'<div class="table-wrap">{cap}<table>{head}<tbody>{"".join(body)}</tbody></table></div>')
        return self

    def figure(self, fig_or_png_bytes: Any, caption: str = "", dpi: int = 120) -> Self:
        """An embedded figure: a matplotlib Figure (rendered to PNG at ``dpi``, then closed) or PNG bytes."""
        png = _to_png(fig_or_png_bytes, dpi)
        data = base64.b64encode(png).decode("ascii")
        alt = _esc(caption or "figure")
        cap = f"<figcaption>{_esc(caption)}</figcaption>" if caption else ""
        self._parts.append(f'<figure><img src="data:image/png;base64,{data}" alt="{alt}">{cap}</figure>')
        return self

    def code(self, text: str) -> Self:
        """Preformatted text (e.g. a printed equation or a solver log), escaped, whitespace kept."""
        self._parts.append(f"<pre><code>{_esc(text)}</code></pre>")
        return self

    def note(self, text: str, kind: str = "info") -> Self:
        """A highlighted remark: ``kind="info"`` (blue) or ``"warn"`` (amber)."""
        if kind not in _NOTE_KINDS:
            raise ValueError(f"The 'kind' parameter of Report.note must be one of {_NOTE_KINDS}. Got {kind!r} instead.")
        label = "Note" if kind == "info" else "Warning"
        self._parts.append(
            f'<div class="note {kind}" role="note"><span class="note-kind">{label}:</span>{_esc(text)}</div>'
        )
        return self

    # ------------------------------------------------------------------ output

    @property
    def headings(self) -> list[tuple[int, str, str]]:
        """``(level, text, anchor)`` of every heading, in order."""
        return [(p.level, p.text, p.anchor) for p in self._parts if isinstance(p, _Heading)]

    def to_html(self) -> str:
        """The complete HTML document."""
        from robocal import __version__

        body = []
        for p in self._parts:
            if isinstance(p, _Heading):
                body.append(
                    f'<h{p.level} id="{p.anchor}">{_esc(p.text)}'
                    f'<a class="anchor" href="#{p.anchor}" aria-label="link to this section">#</a></h{p.level}>'
                )
            else:
                body.append(p)
        sub = f'<p class="subtitle">{_esc(self.subtitle)}</p>' if self.subtitle else ""
        return (
            "<!DOCTYPE html>\n"
            '<html lang="en">\n<head>\n<meta charset="utf-8">\n'
            '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
            '<meta name="generator" content="robocal">\n'
            f"<title>{_esc(self.title)}</title>\n<style>{_CSS}</style>\n</head>\n<body>\n<main>\n"
            f"<header><h1>{_esc(self.title)}</h1>{sub}</header>\n"
            f"{self._toc()}\n" + "\n".join(body) + "\n"
            f"<footer>Generated by robocal {_esc(__version__)}. Self-contained: no external resources.</footer>\n"
            "</main>\n</body>\n</html>\n"
        )

    def save(self, path: str | Path) -> Path:
        """Write the document to ``path`` atomically (UTF-8); returns the path."""
        return write_text(path, self.to_html())

    def _toc(self) -> str:
        heads = self.headings
        if not heads:
            return ""
        out = ['<nav class="toc" aria-label="contents"><p class="toc-title">Contents</p>']
        depth = 0  # number of open <ol>
        levels: list[int] = []
        for level, text, anchor in heads:
            if not levels or level > levels[-1]:
                out.append("<ol>")
                levels.append(level)
                depth += 1
            else:
                out.append("</li>")
                while len(levels) > 1 and level < levels[-1]:
                    out.append("</ol></li>")
                    levels.pop()
                    depth -= 1
            out.append(f'<li><a href="#{anchor}">{_esc(text)}</a>')
        for _ in range(depth):
            out.append("</li></ol>")
        out.append("</nav>")
        return "".join(out)


def _check_float_fmt(float_fmt: str, where: str) -> None:
    try:
        float_fmt.format(1.5)
    except (ValueError, IndexError, KeyError, AttributeError, TypeError):
        raise ValueError(
            f"The 'float_fmt' parameter of {where} must be a str.format pattern for one float, e.g. '{{:.4g}}'. "
            f"Got {float_fmt!r} instead."
        ) from None


def _table_rows(data: Any, columns: Sequence[str] | None) -> tuple[list[str] | None, list[list[Any]]]:
    """Header (or None) and rows of plain Python values."""
    where = "The 'df_or_rows' parameter of Report.table"
    if hasattr(data, "columns") and hasattr(data, "itertuples") and hasattr(data, "index"):  # a DataFrame
        df = data
        if columns is not None:
            missing = [c for c in columns if c not in df.columns]
            if missing:
                raise ValueError(
                    f"The 'columns' parameter of Report.table names columns the DataFrame lacks: {missing}. "
                    f"It has {list(map(str, df.columns))}."
                )
            df = df[list(columns)]
        df_header = [str(c) for c in df.columns]
        df_rows = [list(r) for r in df.itertuples(index=False, name=None)]
        if type(df.index).__name__ != "RangeIndex":
            df_header = [str(df.index.name or ""), *df_header]
            df_rows = [[idx, *r] for idx, r in zip(df.index, df_rows, strict=True)]
        return df_header, df_rows
    if isinstance(data, np.ndarray):
        if data.ndim != 2:
            raise ValueError(f"{where} must be 2-D when it is an array. Got shape {data.shape} instead.")
        data = data.tolist()
    if isinstance(data, str | bytes) or not isinstance(data, Iterable):
        raise ValueError(
            f"{where} must be a DataFrame, a 2-D array or a sequence of rows. Got {type(data).__name__} instead."
        )
    rows_in = list(data)
    if rows_in and all(isinstance(r, Mapping) for r in rows_in):
        keys: list[Any] = list(columns) if columns is not None else []
        if columns is None:
            for r in rows_in:
                keys.extend(k for k in r if k not in keys)
        return [str(k) for k in keys], [[r.get(k) for k in keys] for r in rows_in]
    rows: list[list[Any]] = []
    for i, r in enumerate(rows_in):
        if isinstance(r, str | bytes | Mapping) or not isinstance(r, Iterable):
            raise ValueError(f"{where} must hold rows that are sequences. Row {i} is {type(r).__name__}.")
        rows.append(list(r))
    header = None if columns is None else [str(c) for c in columns]
    width = len(header) if header is not None else (len(rows[0]) if rows else 0)
    for i, r in enumerate(rows):
        if len(r) != width:
            what = f"len(columns) = {width}" if header is not None else f"row 0's {width}"
            raise ValueError(f"{where} must have rows of equal length: row {i} has {len(r)} cells, expected {what}.")
    return header, rows


def _to_png(obj: Any, dpi: int) -> bytes:
    """PNG bytes of a matplotlib Figure (closed afterwards) or of PNG bytes given as such."""
    if isinstance(obj, bytes | bytearray | memoryview):
        png = bytes(obj)
        if not png.startswith(PNG_SIGNATURE):
            raise ValueError(
                "The 'fig_or_png_bytes' parameter of Report.figure must be a matplotlib Figure or PNG bytes. "
                "Got bytes that do not start with the PNG signature instead."
            )
        return png
    if not hasattr(obj, "savefig"):
        raise ValueError(
            "The 'fig_or_png_bytes' parameter of Report.figure must be a matplotlib Figure or PNG bytes. "
            f"Got {type(obj).__name__} instead."
        )
    if not isinstance(dpi, int | np.integer) or not 30 <= dpi <= 600:
        raise ValueError(f"The 'dpi' parameter of Report.figure must be an int in [30, 600]. Got {dpi!r} instead.")
    buf = io.BytesIO()
    try:
        obj.savefig(buf, format="png", dpi=int(dpi), metadata={"Software": None})
    finally:
        plt = sys.modules.get("matplotlib.pyplot")
        if plt is not None:
            plt.close(obj)
    return buf.getvalue()


# ------------------------------------------------------------------------------------------------ page check

#: a Python / numpy repr on a page: ``PlanConfig(n=..``, ``np.str_('B1')``, ``array([``, ``{'a': ..}``, ``['a', ..]``
_REPR = re.compile(
    r"\b[A-Z][A-Za-z]+\((?:[a-z_]+=)|\bnp\.[a-z_0-9]+\(|\barray\(\[|\{\s*'[^']*'\s*:|\[\s*'[^']*'\s*,|"
    r"\bdtype=|<[a-z_.]+ object at 0x"
)
#: a cell that shows Python's spelling of a value instead of words or a blank
_RAW_CELL = re.compile(r"<t[dh][^>]*>\s*(True|False|None|nan|NaN|inf|-inf)\s*</t[dh]>")
_TAG = re.compile(r"<[^>]+>")
#: the longest run of non-space characters a line of text may hold (a long path or key breaks the layout)
LONGEST_TOKEN = 60


def _visible_text(page: str) -> str:
    body = page.split("<body", 1)[-1]
    body = re.sub(r"<style.*?</style>", " ", body, flags=re.S)
    body = re.sub(r'src="data:[^"]*"', " ", body)
    return html.unescape(_TAG.sub(" ", body))


def page_problems(page: str) -> list[str]:
    """What a reader should never see on a report page: a Python repr, ``nan`` / ``True`` / ``False`` in the text
    or ``None`` as a cell, a token too long to wrap (wider than the page; a path breaks at the edge), a
    preformatted line over 110 characters.
    Returns one line per problem (empty: the page is clean). Tables themselves scroll inside their frame."""
    out: list[str] = []
    text = _visible_text(page)
    for m in _REPR.finditer(text):
        out.append(f"a Python repr: ...{text[max(0, m.start() - 30) : m.end() + 40]!s}...")
    for m in _RAW_CELL.finditer(page):
        out.append(f"a raw value in a cell: {m.group(0)}")
    for m in re.finditer(r"(?<![\w.])(nan|NaN|True|False)(?![\w.])", text):
        out.append(f"{m.group(1)!r} in the text: ...{text[max(0, m.start() - 40) : m.end() + 20]}...")
    for tok in set(text.split()):
        if len(tok) > LONGEST_TOKEN and "/" not in tok:  # paths break at the box's edge (overflow-wrap)
            out.append(f"an unbreakable token of {len(tok)} characters: {tok[:80]}")
    for pre in re.findall(r"<pre[^>]*>(.*?)</pre>", page, flags=re.S):
        for line in html.unescape(_TAG.sub("", pre)).splitlines():
            if len(line) > 110:
                out.append(f"a preformatted line of {len(line)} characters: {line[:80]}...")
    return out


_LAYOUT_PROBE = """<!DOCTYPE html><html><body><div id="out">pending</div><script>
const pages = %s, width = %d, res = {}; let left = pages.length;
for (const p of pages) {
  const f = document.createElement("iframe"); f.style.width = width + "px"; f.style.height = "900px"; f.src = p;
  f.onload = () => {
    try {
      const d = f.contentDocument, w = d.documentElement.clientWidth, probs = [];
      const sw = d.documentElement.scrollWidth;
      if (sw > w + 1) probs.push("the page is " + sw + " px wide");
      d.querySelectorAll(".table-wrap, pre, figure, .note, p, h2, h3").forEach((e) => {
        if (e.scrollWidth > e.clientWidth + 1)
          probs.push(e.tagName.toLowerCase() + " " + e.scrollWidth + " px in " + e.clientWidth + " px: "
                     + e.textContent.trim().slice(0, 70));
      });
      res[p] = probs;
    } catch (err) { res[p] = ["not checked: " + err]; }
    if (--left === 0) document.getElementById("out").textContent = JSON.stringify(res);
  };
  document.body.appendChild(f);
}
</script></body></html>
"""


def layout_problems(
    pages: Sequence[str | Path], width: int = 1000, chromium: str | None = None
) -> dict[str, list[str]] | None:
    """Render ``pages`` in headless Chromium at ``width`` px and list what is wider than its box (the page itself,
    a table, a preformatted block, a figure, a paragraph): ``{page: [problem, ...]}``. None when no Chromium is
    installed (``chromium`` / ``chromium-browser`` / ``google-chrome`` on PATH, or the ``chromium`` argument)."""
    import json
    import shutil
    import subprocess
    import tempfile

    exe = chromium or next(
        (p for p in (shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome")) if p), None
    )
    if exe is None:
        return None
    with tempfile.TemporaryDirectory() as tmp:
        names = []
        for k, page in enumerate(pages):  # one folder, so the probe may read every page (file:// same origin)
            name = f"page{k}.html"
            Path(tmp, name).write_bytes(Path(page).read_bytes())
            names.append(name)
        probe = Path(tmp, "probe.html")
        probe.write_text(_LAYOUT_PROBE % (json.dumps(names), width), encoding="utf-8")
        cmd = [
            exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
            "--disable-component-update", "--disable-sync", "--no-first-run", "--allow-file-access-from-files",
            "--virtual-time-budget=15000", "--dump-dom", probe.as_uri(),
        ]  # fmt: skip
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=120).stdout
    m = re.search(r'<div id="out">(.*?)</div>', out, flags=re.S)
    if m is None or m.group(1) == "pending":
        raise RuntimeError(f"the layout probe did not finish in Chromium ({exe}): {out[-500:]!s}")
    found = json.loads(html.unescape(m.group(1)))
    return {str(page): found[name] for page, name in zip(pages, names, strict=True)}


def words(value: Any) -> str:
    """A summary value as words (``x 0.12..0.34, rows 12``), never a Python dict or list repr."""
    if isinstance(value, dict):
        return ", ".join(f"{k.replace('_', ' ')} {words(v)}" for k, v in value.items())
    if isinstance(value, list | tuple):
        return "..".join(words(v) for v in value) if len(value) == 2 else ", ".join(words(v) for v in value)
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)
