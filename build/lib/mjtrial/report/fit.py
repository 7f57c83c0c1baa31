"""Text that fits its figure, whatever the task names its conditions.

The built-in tasks' short names fit any layout; another task's ("frictionloss_doubled
(frictionloss_scale 2)") push a legend past the canvas or one subplot's title into the next.
Each helper measures the text as it will be drawn (the figure's own renderer and fonts) and
chooses columns or line breaks until it fits the width it has.
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from typing import Any

from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg, RendererAgg
from matplotlib.figure import Figure
from matplotlib.legend import Legend
from matplotlib.text import Text

MAX_LEGEND_COLUMNS = 3


def _renderer(figure: Figure) -> RendererAgg:
    """The renderer the figure is measured with (Agg, as the PNG is drawn)."""
    canvas = figure.canvas
    if not isinstance(canvas, FigureCanvasAgg):
        canvas = FigureCanvasAgg(figure)
    return canvas.get_renderer()


def _width(artist: Artist, figure: Figure) -> float:
    """The artist's drawn width in pixels."""
    return artist.get_window_extent(_renderer(figure)).width


def wrapped(text: str, *, fraction: float) -> str:
    """`text` broken into lines of at most `fraction` of its longest line's length (at word
    boundaries where it can, inside a word where it must)."""
    lines = text.split("\n")
    width = max(8, int(max(len(line) for line in lines) * fraction))
    return "\n".join(textwrap.fill(line, width) for line in lines)


def fit_text(text: Text, *, width: float | None = None, height: float | None = None) -> Text:
    """Break `text` into lines until its drawn box is at most `width` pixels wide and `height`
    pixels high (a rotated label's length is its height)."""
    figure = text.get_figure(root=True)
    for _ in range(4):
        box = text.get_window_extent(_renderer(figure))
        over = max(
            box.width / width if width else 0.0,
            box.height / height if height else 0.0,
        )
        if over <= 1:
            break
        text.set_text(wrapped(text.get_text(), fraction=0.95 / over))
    return text


def fitted_title(ax: Axes, text: str, *, width: float) -> None:
    """`ax`'s title, broken into lines until it is at most `width` pixels wide."""
    fit_text(ax.set_title(text), width=width)


def fitted_legend(
    owner: Figure | Axes,
    handles: Sequence[Artist],
    labels: Sequence[str],
    *,
    width: float,
    **kwargs: Any,
) -> Legend:
    """A legend of `owner` (a figure's, or an axes') at most `width` pixels wide: in as many
    columns as fit (at most `MAX_LEGEND_COLUMNS`), its labels broken into lines when even one
    column is too wide. `kwargs` go to `legend()` (placement, spacing)."""
    figure = owner if isinstance(owner, Figure) else owner.figure
    labels = list(labels)
    legend = owner.legend(handles, labels, **kwargs)  # with nothing labelled, an empty one
    if not labels:
        return legend
    legend.remove()
    for ncols in range(min(len(labels), MAX_LEGEND_COLUMNS), 0, -1):
        legend = owner.legend(handles, labels, ncols=ncols, **kwargs)
        drawn = _width(legend, figure)
        if drawn <= width:
            return legend
        legend.remove()
    for _ in range(4):
        labels = [wrapped(label, fraction=0.95 * width / drawn) for label in labels]
        legend = owner.legend(handles, labels, ncols=1, **kwargs)
        drawn = _width(legend, figure)
        if drawn <= width:
            break
        legend.remove()
    return legend


def figure_legend_below(figure: Figure, **kwargs: Any) -> Legend:
    """The figure's legend under its axes (no data point can sit under it), fitted to its width:
    every axes' labelled artists, in order."""
    handles, labels = [], []
    for ax in figure.axes:
        h, labelled = ax.get_legend_handles_labels()
        handles += h
        labels += labelled
    return fitted_legend(
        figure, handles, labels, width=figure.bbox.width, loc="outside lower center", **kwargs
    )
