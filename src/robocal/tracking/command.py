"""``python -m robocal.tracking flush | ui-url | ui``."""

from __future__ import annotations

from pathlib import Path

from robocal.tracking.pending import flush, pending_dir
from robocal.tracking.store import ensure_store
from robocal.tracking.ui import serve_ui
from robocal.tracking.view import headline_metrics, runs_view_url, set_runs_view


def main(argv: list[str] | None = None) -> int:
    import argparse

    parser = argparse.ArgumentParser(prog="python -m robocal.tracking", description="MLflow runs of robocal")
    sub = parser.add_subparsers(dest="action", required=True)
    f = sub.add_parser("flush", help="write the pending runs (mlflow-pending/) to MLflow; waits for a flusher at work")
    f.add_argument("--dir", default=None, help="the pending-runs folder (default: the one of the tracking store)")
    u = sub.add_parser("ui-url", help="print the MLflow UI's address of the runs table (what `make ui` opens)")
    u.add_argument("--port", type=int, default=5000)
    s = sub.add_parser("ui", help="flush, store the runs table's view, print its address and serve the MLflow UI")
    s.add_argument("--port", type=int, default=5000)
    s.add_argument("--host", default="127.0.0.1")
    args = parser.parse_args(argv)
    if args.action == "ui-url":
        exp_id = ensure_store()
        set_runs_view(exp_id, headline_metrics())
        print(runs_view_url(exp_id, f"http://127.0.0.1:{args.port}", view=True))
        return 0
    if args.action == "ui":
        return serve_ui(args.host, args.port)
    n = flush(args.dir)
    left = [d for d in (Path(args.dir) if args.dir else pending_dir()).glob("*") if d.is_dir()]
    print(f"robocal tracking: {n} pending run(s) written" + (f"; {len(left)} could not be" if left else ""))
    return 1 if left else 0
