"""``make exps``: the DVC experiments side by side, readable on an 80-column terminal.

``dvc exp show --json | python -m robocal.exps [--width N]`` prints one table -- the experiment, then the headline
metrics under short names (:data:`HEADLINE`, mm) -- and under it, per experiment, the parameters that differ
between the experiments shown (the robot and the scenario by name only) and the stages that did not end ok.
``dvc exp show`` itself puts every status, metric and changed parameter in one row: at 80 columns its cells
shrink to "…".
"""

from __future__ import annotations

import json
import shutil
import sys
import textwrap
from dataclasses import dataclass, field
from typing import Any

#: (metric key in reports/metrics/*.json, column label): the numbers an experiment is compared by (mm)
HEADLINE = (
    ("fit_rms_mm", "fit"),
    ("val_mean_mm", "val"),
    ("thermal_resid_rms_mm", "thermal"),
    ("comp_proposed_mean_mm", "comp"),
    ("disc_rms_mm", "discover"),
    ("disc_val_mean_mm", "disc val"),
)
#: parameter sections shown by name only (their ``name`` key): the rest of a robot or scenario is its file's
BY_NAME = ("robot", "scenario")
NAME_WIDTH = 22


@dataclass
class Row:
    name: str
    params: dict[str, Any] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)
    status: dict[str, str] = field(default_factory=dict)


def _flat(d: Any, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    if isinstance(d, dict):
        for k, v in d.items():
            out.update(_flat(v, f"{prefix}{k}."))
    else:
        out[prefix[:-1]] = d
    return out


def _row(entry: dict[str, Any]) -> Row | None:
    data = entry.get("data") or {}
    if not data:
        return None
    rev = str(entry.get("rev", "?"))
    name = entry.get("name") or (rev if rev == "workspace" else rev[:7])
    row = Row(name)
    for f in (data.get("params") or {}).values():
        for k, v in _flat((f or {}).get("data") or {}).items():
            top, _, rest = k.partition(".")
            if top in BY_NAME and rest != "name":
                continue
            row.params[k] = v
    for path, f in (data.get("metrics") or {}).items():
        stage = path.rsplit("/", 1)[-1].removesuffix(".json")
        for k, v in ((f or {}).get("data") or {}).items():
            if k == stage and isinstance(v, str):
                row.status[stage] = v
            else:
                row.metrics[k] = v
    return row


def rows_of(show: list[dict[str, Any]]) -> list[Row]:
    """The rows of ``dvc exp show --json`` (DVC 3): the workspace, each baseline commit and its experiments."""
    rows: list[Row] = []
    for entry in show:
        r = _row(entry)
        if r is not None:
            rows.append(r)
        for exp in entry.get("experiments") or []:
            for rev in exp.get("revs") or []:
                r = _row({**rev, "name": rev.get("name") or exp.get("name")})
                if r is not None:
                    rows.append(r)
    return rows


def _num(v: Any) -> str:
    if isinstance(v, bool) or not isinstance(v, int | float):
        return "-" if v is None else str(v)
    return f"{v:.3g}" if abs(v) < 1e4 else f"{v:.0f}"


def table(rows: list[Row], width: int = 80) -> str:
    """The experiments' table and, under it, what sets each apart (lines of at most ``width`` characters)."""
    cols = [(k, lab) for k, lab in HEADLINE if any(k in r.metrics for r in rows)]
    cells = [[_num(r.metrics.get(k)) for k, _ in cols] for r in rows]
    widths = [max([len(lab), *(len(c[i]) for c in cells)]) for i, (_, lab) in enumerate(cols)]
    name_w = min(NAME_WIDTH, max([len("experiment"), *(len(r.name) for r in rows)]))

    def line(name: str, vals: list[str]) -> str:
        name = name if len(name) <= name_w else name[: name_w - 1] + "…"
        return "  ".join([name.ljust(name_w), *(v.rjust(w) for v, w in zip(vals, widths, strict=True))]).rstrip()

    out = [line("experiment", [lab for _, lab in cols]) + ("   (mm)" if cols else "")]
    out += [line(r.name, c) for r, c in zip(rows, cells, strict=True)]
    keys = sorted({k for r in rows for k in r.params})
    changed = [k for k in keys if len({json.dumps(r.params.get(k), sort_keys=True) for r in rows}) > 1]
    stages = list(dict.fromkeys(s for r in rows for s in r.status))
    differ = [s for s in stages if len({r.status.get(s) for r in rows}) > 1]
    notes = []
    for r in rows:
        parts = [f"{k}={r.params.get(k)}" for k in changed]
        off = [f"{s} {r.status.get(s, 'not run')}" for s in differ if r.status.get(s) != "ok"]
        if off:
            parts.append("not ok: " + ", ".join(off))
        if parts:
            notes += _wrap(f"{r.name}: " + "; ".join(parts), width, "    ")
    if notes:
        out += ["", "what differs (parameters; stages not ok in some):", *notes]
    out.append("")
    out.append("metrics: " + ", ".join(f"{lab} = {k}" for k, lab in cols) + "; all columns: dvc exp show")
    return "\n".join(out[:-1] + _wrap(out[-1], width)) + "\n"


def _wrap(text: str, width: int, indent: str = "") -> list[str]:
    """Lines of at most ``width``; a path or value longer than a line is cut with "…", not broken at its hyphens."""
    lines = textwrap.wrap(text, width, subsequent_indent=indent, break_on_hyphens=False, break_long_words=False)
    return [x if len(x) <= width else x[: width - 1] + "…" for x in lines]


def main(argv: list[str] | None = None) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="python -m robocal.exps", description=__doc__.split("\n\n")[0])
    p.add_argument("file", nargs="?", default="-", help="dvc exp show --json output (default: stdin)")
    p.add_argument("--width", type=int, default=None, help="line width (default: the terminal's, at most 100)")
    args = p.parse_args(argv)
    text = sys.stdin.read() if args.file == "-" else open(args.file, encoding="utf-8").read()
    width = args.width or min(100, shutil.get_terminal_size((80, 24)).columns)
    sys.stdout.write(table(rows_of(json.loads(text)), width))
    return 0


if __name__ == "__main__":
    sys.exit(main())
