"""The plan report's pose views read at a glance: no tick labels running together (issue 30 item 10)."""

from __future__ import annotations

import itertools
from types import SimpleNamespace
from typing import Any

import numpy as np

from robocal.plan.output import poses_figure


def overlapping_tick_labels(fig: Any) -> list[tuple[str, str]]:
    """Pairs of neighbouring tick labels whose drawn boxes overlap (or touch within 2 px), per axis."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    pairs = []
    for ax in fig.axes:
        for axis, lo, hi in ((ax.xaxis, "x0", "x1"), (ax.yaxis, "y0", "y1")):
            labels = [t for t in axis.get_ticklabels() if t.get_visible() and t.get_text()]
            boxes = sorted(
                ((t.get_window_extent(renderer), t.get_text()) for t in labels), key=lambda b: getattr(b[0], lo)
            )
            for (a, ta), (b, tb) in itertools.pairwise(boxes):
                if getattr(a, hi) + 2.0 > getattr(b, lo):
                    pairs.append((ta, tb))
    return pairs


def _plan_like_the_default() -> Any:
    """The default plan's geometry: candidates over x -600..1600, y -700..1200 mm, the tracker 2.6 m out in y."""
    rng = np.random.default_rng(0)
    xyz = np.column_stack([rng.uniform(-600, 1600, 1500), rng.uniform(-700, 1200, 1500), rng.uniform(100, 2100, 1500)])
    problem = SimpleNamespace(
        cand=SimpleNamespace(targets_mm=xyz[:, None, :]),
        config=SimpleNamespace(tracker=SimpleNamespace(position_mm=[900.0, 2600.0, 330.0])),
    )
    return SimpleNamespace(problem=problem, idx=np.arange(0, 1500, 50))


def test_pose_views_tick_labels_do_not_overlap() -> None:
    fig = poses_figure(_plan_like_the_default())
    assert overlapping_tick_labels(fig) == []
    top = fig.axes[0]
    assert len([t for t in top.get_xticklabels() if t.get_text()]) >= 3  # still a scale to read
