"""Compare two discovery results (``discovery.json`` of ``robocal discover`` / the pipeline's discover stage).

    python benchmarks/compare_discovery.py BEFORE/discovery.json AFTER/discovery.json [--tol 1e-6]

Prints whether the named effects are the same (keys, in order), the headline figures side by side (RMS before /
after, noise floor, cross-validated error, validation means), and every numeric value that differs by more
than ``--tol`` relative (timings excluded), largest first. Exit status 1 when the named effects differ.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

HEADLINE = (
    ("rms_before_mm",),
    ("rms_after_mm",),
    ("noise_floor_mm",),
    ("cross_validation", "cv_mean_position_mm"),
    ("cross_validation", "cv_rms_position_mm"),
    ("validation", "geometric", "mean_position_mm"),
    ("validation", "discovered", "mean_position_mm"),
    ("validation", "final", "mean_position_mm"),
)


def leaves(obj: Any, path: str = "") -> dict[str, float]:
    out: dict[str, float] = {}
    if isinstance(obj, dict):
        for k, v in obj.items():
            if "time_s" in str(k):
                continue
            out.update(leaves(v, f"{path}.{k}" if path else str(k)))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out.update(leaves(v, f"{path}[{i}]"))
    elif isinstance(obj, (int, float)) and not isinstance(obj, bool):
        out[path] = float(obj)
    return out


def get(d: dict[str, Any], path: tuple[str, ...]) -> Any:
    for p in path:
        if not isinstance(d, dict) or p not in d:
            return None
        d = d[p]
    return d


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("before")
    ap.add_argument("after")
    ap.add_argument("--tol", type=float, default=1e-6, help="relative difference reported (default 1e-6)")
    ap.add_argument("--show", type=int, default=25, help="differing values listed (largest first)")
    a = ap.parse_args()
    with open(a.before) as f:
        b = json.load(f)
    with open(a.after) as f:
        c = json.load(f)
    kb = [n["key"] for n in b.get("named", [])]
    kc = [n["key"] for n in c.get("named", [])]
    same = kb == kc
    print(f"named effects {'the same' if same else 'DIFFER'}:\n  before {kb}\n  after  {kc}")
    for p in HEADLINE:
        vb, vc = get(b, p), get(c, p)
        if vb is None and vc is None:
            continue
        print(f"  {'.'.join(p):45s} {vb!s:>22} {vc!s:>22}")
    lb, lc = leaves(b), leaves(c)
    diffs = []
    for k in sorted(set(lb) & set(lc)):
        x, y = lb[k], lc[k]
        if math.isnan(x) and math.isnan(y):
            continue
        rel = abs(x - y) / max(abs(x), abs(y), 1e-300)
        if rel > a.tol:
            diffs.append((rel, k, x, y))
    diffs.sort(reverse=True)
    only = sorted(set(lb) ^ set(lc))
    print(f"{len(diffs)} of {len(set(lb) & set(lc))} numeric values differ by more than {a.tol:g} relative; "
          f"{len(only)} present in one file only")  # fmt: skip
    for rel, k, x, y in diffs[: a.show]:
        print(f"  {rel:9.2e}  {k}: {x!r} -> {y!r}")
    for k in only[: a.show]:
        print(f"  only in {'before' if k in lb else 'after'}: {k}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
