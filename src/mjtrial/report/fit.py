"""Text that fits its figure, whatever the task names its conditions.

The built-in tasks' short names fit any layout; another task's ("frictionloss_doubled
(frictionloss_scale 2)") push a legend past the canvas or one subplot's title into the next.
Each helper measures the text as it will be drawn (the figure's own renderer and fonts) and
chooses columns or line breaks until it fits the width it has.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Any

from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg, RendererAgg
from matplotlib.figure import Figure
from matplotlib.legend import Legend
from matplotlib.text import Text

MAX_LEGEND_COLUMNS = 3
MIN_FONT_SIZE = 8.0  # points: the figures' smallest text


def _renderer(figure: Figure) -> RendererAgg:
    """The renderer the figure is measured with (Agg, as the PNG is drawn)."""
    canvas = figure.canvas
    if not isinstance(canvas, FigureCanvasAgg):
        canvas = FigureCanvasAgg(figure)
    return canvas.get_renderer()


def _width(artist: Artist, figure: Figure) -> float:
    """The artist's drawn width in pixels."""
    return artist.get_window_extent(_renderer(figure)).width


# Where an identifier may break when a line of whole words is still too wide: after one of
# these (`frictionloss_|doubled`), never inside a run of letters or digits.
_IDENTIFIER_BREAK = re.compile(r"(?<=[_./-])(?=\S)")


def _fill(line: str, width: int, *, identifiers: bool) -> str:
    """`line` broken greedily into lines of at most `width` characters, at spaces (and, with
    `identifiers`, after `_ . / -`); a piece longer than `width` stays whole."""
    pieces: list[tuple[str, str]] = []  # (glue before it, piece)
    for i, word in enumerate(line.split()):
        parts = _IDENTIFIER_BREAK.split(word) if identifiers else [word]
        pieces += [(" " if i and not j else "", part) for j, part in enumerate(parts)]
    lines: list[str] = []
    for glue, piece in pieces:
        if lines and len(lines[-1]) + len(glue) + len(piece) <= width:
            lines[-1] += glue + piece
        else:
            lines.append(piece)
    return "\n".join(lines)


def wrapped(text: str, *, fraction: float, identifiers: bool = False) -> str:
    """`text` broken into lines of at most `fraction` of its longest line's length, at word
    boundaries (and, with `identifiers`, after `_ . / -` in a long name); never inside a word."""
    lines = text.split("\n")
    width = max(1, int(max(len(line) for line in lines) * fraction))
    return "\n".join(_fill(line, width, identifiers=identifiers) for line in lines)


def _over(text: Text, width: float | None, height: float | None) -> float:
    """How many times too big `text`'s drawn box is (<= 1: it fits)."""
    box = text.get_window_extent(_renderer(text.get_figure(root=True)))
    return max(box.width / width if width else 0.0, box.height / height if height else 0.0)


def fit_text(text: Text, *, width: float | None = None, height: float | None = None) -> Text:
    """Break `text` into lines until its drawn box is at most `width` pixels wide and `height`
    pixels high (a rotated label's length is its height): at spaces first, then after `_ . / -`
    inside long names, never inside a word; a label that still does not fit goes down to
    `MIN_FONT_SIZE`."""
    original = text.get_text()
    for identifiers in (False, True):
        chars = max(len(line) for line in original.split("\n"))
        for _ in range(24):
            over = _over(text, width, height)
            if over <= 1:
                return text
            chars = min(chars - 1, int(chars * 0.97 / over))
            if chars < 1:
                break
            text.set_text(
                wrapped(
                    original,
                    fraction=chars / max(map(len, original.split("\n"))),
                    identifiers=identifiers,
                )
            )
    while _over(text, width, height) > 1 and text.get_fontsize() > MIN_FONT_SIZE:
        text.set_fontsize(max(MIN_FONT_SIZE, text.get_fontsize() - 0.5))
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
        labels = [
            wrapped(label, fraction=0.95 * width / drawn, identifiers=True) for label in labels
        ]
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


def fit_axes_labels(figure: Figure) -> None:
    """The figure's title to its width, every axes' title to the axes' width and its y-label to
    the axes' height, as the layout places them (a long series name or condition otherwise runs
    past the canvas and is cut)."""
    figure.draw_without_rendering()
    suptitle = getattr(figure, "_suptitle", None)  # matplotlib keeps no public handle
    if suptitle is not None and suptitle.get_text():
        fit_text(suptitle, width=0.98 * figure.bbox.width)
    for ax in figure.axes:
        box = ax.bbox
        if ax.title.get_text():
            fit_text(ax.title, width=box.width)
        label = ax.yaxis.label
        if label.get_text() and label.get_visible():
            fit_text(label, height=box.height)
