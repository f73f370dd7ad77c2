"""What a drawn figure must look like, checked on its rendered pixels: every legend
inside the figure and clear of every axes, and how many pixels of a colour an axes
shows. Used by test_plots (synthetic evaluations) and test_logtools (a real flight log).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import to_rgb
from matplotlib.figure import Figure
from matplotlib.legend import Legend


def _render(fig: Figure) -> Any:
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return canvas.get_renderer()


def figure_legends(fig: Figure) -> list[Legend]:
    own = [ax.get_legend() for ax in fig.axes]
    return list(fig.legends) + [leg for leg in own if leg is not None]


def assert_legends_clear(fig: Figure) -> int:
    """Every legend lies inside the figure and overlaps no axes: neither its data area
    nor its ticks, labels, title or annotations. Returns how many legends there are."""
    renderer = _render(fig)
    legends = figure_legends(fig)
    for leg in legends:
        bb = leg.get_window_extent(renderer)
        f = fig.bbox
        assert f.x0 - 1 <= bb.x0 and bb.x1 <= f.x1 + 1, f"legend cut off: {bb} in {f}"
        assert f.y0 - 1 <= bb.y0 and bb.y1 <= f.y1 + 1, f"legend cut off: {bb} in {f}"
        for ax in fig.axes:
            own = ax.get_legend()
            if own is not None:
                own.set_visible(False)
            try:
                ax_bb = ax.get_tightbbox(renderer)
            finally:
                if own is not None:
                    own.set_visible(True)
            assert ax_bb is not None
            labels = [t.get_text() for t in leg.get_texts()]
            assert not bb.overlaps(ax_bb), f"legend {labels} over axes {ax.get_ylabel()!r}"
    return len(legends)


def colour_pixels(fig: Figure, ax: Axes, colour: Any, tol: float = 0.08) -> int:
    """How many pixels inside ``ax``'s data area show ``colour`` (the rendered PNG)."""
    _render(fig)
    canvas = fig.canvas
    assert isinstance(canvas, FigureCanvasAgg)
    img = np.asarray(canvas.buffer_rgba())[:, :, :3].astype(np.float64) / 255.0
    h = img.shape[0]
    bb = ax.bbox
    sub = img[int(h - bb.y1) + 2 : int(h - bb.y0) - 2, int(bb.x0) + 2 : int(bb.x1) - 2]
    return int((np.abs(sub - np.array(to_rgb(colour))).max(axis=2) < tol).sum())
