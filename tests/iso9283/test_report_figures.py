"""The certificate's scatter figure: a legend that can be read and covers no data (issue 30 item 10)."""

from __future__ import annotations

import numpy as np
import pytest

from robocal.iso9283.analysis import IsoResult, PoseResult
from robocal.iso9283.report import scatter_figure


def _result(n_poses: int, scale: float) -> IsoResult:
    rng = np.random.default_rng(1)
    poses = []
    for k in range(n_poses):
        d = rng.normal(0.0, scale, (30, 3))
        poses.append(
            PoseResult(
                pose=f"P{k + 1}",
                n_cycles=30,
                approach="-x",
                commanded_mm=np.zeros(3),
                barycentre_mm=np.zeros(3),
                AP_p_mm=1.0,
                AP_xyz_mm=np.zeros(3),
                RP_l_mm=3.6 * scale,
                l_bar_mm=1.6 * scale,
                S_l_mm=0.7 * scale,
                deviations_mm=d,
            )
        )
    return IsoResult(poses, {}, None, None, None, [])


@pytest.mark.parametrize("n_poses", [5, 2])
def test_scatter_legend_is_outside_the_panels_and_readable(n_poses: int) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = scatter_figure(_result(n_poses, 0.018), _result(n_poses, 0.017), "after")
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    r = canvas.get_renderer()
    assert not any(ax.get_legend() for ax in fig.axes)  # no legend inside a panel
    (legend,) = fig.legends
    box = legend.get_window_extent(r)
    fig_box = fig.bbox
    assert fig_box.x0 <= box.x0 and box.x1 <= fig_box.x1 and box.y1 <= fig_box.y1 + 1  # all of it on the figure
    for ax in fig.axes:
        assert not box.overlaps(ax.get_tightbbox(r)), ax.get_title()  # covers no panel, title or tick label
    texts = [t.get_text() for t in legend.get_texts()]
    assert texts == ["before: a cycle", "after: a cycle", "RP_l before (circle)", "RP_l after (circle)"]
    assert min(t.get_fontsize() for t in legend.get_texts()) >= 8
