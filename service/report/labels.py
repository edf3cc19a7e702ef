"""Labels that never overlap: each label is an annotation offset from its point, moved to the first
free spot around it, with a leader line when it had to move away. Text boxes are measured by the
figure's own renderer, so what is checked is what is drawn.

Also :func:`text_overlaps`, which lists every pair of overlapping texts in a drawn figure (the
report's tests hold every figure to none).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from matplotlib.text import Annotation, Text
from matplotlib.ticker import FixedLocator
from matplotlib.transforms import Bbox

GAP_PT = 4.0  # between a label and its point: close enough to read as one
RING_STEP_PT = 6.0  # candidate spots lie on rings around the point, this far apart
RING_ANGLES = 16  # candidate spots per ring
MAX_RING_PT = 160.0  # the farthest a label goes from its point; farther, it is read as another point's
LEADER_PT = 8.0  # a label farther than this from its point gets a leader line to it
PAD_PX = 1.0  # boxes closer than this count as touching


@dataclass
class Label:
    """A label to place: its text at ``xy`` (data coordinates of ``ax``, 2D; a 3D axes' projected
    coordinates), drawn with ``style`` (Text properties)."""

    text: str
    xy: tuple[float, float]
    style: dict


def place_labels(ax, labels: list[Label], avoid: Sequence[Text] = ()) -> list[Annotation]:
    """Draw ``labels`` on ``ax``, each at the first free spot near its point, in the given order.

    A spot is free when the label's box (measured by the renderer) lies inside the axes and meets
    no label placed before it, no text of ``avoid`` (axis names, titles) and no other label's point.
    When no spot is free within MAX_RING_PT, the spot with the least overlap is taken.

    Returns:
        The annotations, in the order of ``labels``.
    """
    fig = ax.figure
    renderer = fig.canvas.get_renderer()
    to_px = fig.dpi / 72.0
    frame = ax.get_window_extent(renderer)
    points = [ax.transData.transform(lb.xy) for lb in labels]
    dots = [Bbox.from_bounds(x - 3, y - 3, 6, 6) for x, y in points]
    taken = [t.get_window_extent(renderer) for t in avoid if t.get_visible() and t.get_text()]
    out = []
    for i, lb in enumerate(labels):
        note = ax.annotate(lb.text, lb.xy, xytext=(0, 0), textcoords="offset points", ha="center", va="center",
                           annotation_clip=False, **lb.style)
        size = note.get_window_extent(renderer)
        half = np.array([size.width, size.height]) / 2 / to_px  # points
        best, best_cost = (0.0, 0.0), np.inf
        for offset in _spots(half):
            note.xyann = offset
            box = note.get_window_extent(renderer)
            cost = (_outside(box, frame) * 1e6 + sum(_overlap(box, b) for b in taken) * 1e3
                    + sum(_overlap(box, d) for k, d in enumerate(dots) if k != i))
            if cost < best_cost:
                best, best_cost = offset, cost
            if cost == 0:
                break
        note.remove()
        leader = np.hypot(*best) - np.hypot(*half) > LEADER_PT
        arrow = {"arrowprops": {"arrowstyle": "-", "color": lb.style.get("color", "black"), "linewidth": 0.8,
                                "shrinkA": 0, "shrinkB": 2}} if leader else {}
        note = ax.annotate(lb.text, lb.xy, xytext=best, textcoords="offset points", ha="center", va="center",
                           annotation_clip=False, **lb.style, **arrow)
        taken.append(note.get_window_extent(renderer))
        out.append(note)
    return out


def _spots(half: np.ndarray):
    """Offsets (points) of a centred label's middle: beside its point first, then on rings."""
    w, h = half
    yield from ((w + GAP_PT, h + GAP_PT), (w + GAP_PT, -h - GAP_PT), (-w - GAP_PT, h + GAP_PT),
                (-w - GAP_PT, -h - GAP_PT), (0.0, h + GAP_PT), (0.0, -h - GAP_PT))
    for r in np.arange(RING_STEP_PT, MAX_RING_PT + RING_STEP_PT, RING_STEP_PT):
        for a in np.linspace(0, 2 * np.pi, RING_ANGLES, endpoint=False):
            yield (np.cos(a) * (w + GAP_PT + r), np.sin(a) * (h + GAP_PT + r))


def _overlap(a: Bbox, b: Bbox) -> float:
    w = min(a.x1, b.x1) - max(a.x0, b.x0) + PAD_PX
    h = min(a.y1, b.y1) - max(a.y0, b.y0) + PAD_PX
    return max(w, 0.0) * max(h, 0.0)


def _outside(box: Bbox, frame: Bbox) -> float:
    """How far (pixels) a box reaches out of the frame."""
    return max(frame.x0 - box.x0, 0) + max(box.x1 - frame.x1, 0) + max(frame.y0 - box.y0, 0) + max(box.y1 - frame.y1, 0)


def hide_colliding_ticks(fig, axes) -> None:
    """Leave out each tick of ``axes`` whose label meets another text (an axis name, a tick label
    of another axis where two axes meet in a 3D view's corner): a number less, never two on one
    another. The ticks left are fixed (a FixedLocator), so later draws keep them. Draws the figure."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    axis_list = [a for ax in axes for a in axes_of(ax)]
    # the ticks as drawn: get_ticklabels() would move a 3D axis's labels to 2D places until the next draw
    tick_ids = {id(t.label1) for a in axis_list for t in a.get_major_ticks()}
    kept = [t.get_window_extent(renderer) for t in drawn_texts(fig) if id(t) not in tick_ids]
    for axis in axis_list:
        locs = axis.get_majorticklocs()
        lo, hi = sorted(axis.get_view_interval())
        keep = []
        for loc, tick in zip(locs, axis.get_major_ticks(len(locs))):  # aligned, as matplotlib's own _update_ticks
            t = tick.label1
            if not (lo <= loc <= hi and t.get_visible() and t.get_text().strip() and _shown(t, fig)):
                keep.append(loc)  # not drawn: nothing to collide
                continue
            box = t.get_window_extent(renderer)
            if not any(_overlap(box, k) > PAD_PX * PAD_PX for k in kept):
                kept.append(box)
                keep.append(loc)
        if len(keep) < len(locs):
            axis.set_major_locator(FixedLocator(keep))
    fig.canvas.draw()


def axes_of(ax):
    return [ax.xaxis, ax.yaxis] + ([ax.zaxis] if hasattr(ax, "zaxis") else [])


def text_overlaps(fig) -> list[tuple[str, str]]:
    """Every pair of texts drawn in a figure whose boxes (from its renderer) overlap. Draws it."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    boxes = [(t.get_text(), t.get_window_extent(renderer)) for t in drawn_texts(fig)]
    return [(a, b) for (a, ba), (b, bb) in itertools.combinations(boxes, 2)
            if min(ba.x1, bb.x1) > max(ba.x0, bb.x0) and min(ba.y1, bb.y1) > max(ba.y0, bb.y0)]


def drawn_texts(fig) -> list[Text]:
    """The visible, non-empty texts of a drawn figure. An axis keeps Tick objects beyond those it
    draws (ticks out of its view, or left over when fewer are asked for); their labels are left out."""
    undrawn = set()
    for ax in fig.axes:
        for axis in axes_of(ax):
            lo, hi = sorted(axis.get_view_interval())
            for locs, ticks in ((axis.get_majorticklocs(), axis.get_major_ticks()),
                                (axis.get_minorticklocs(), axis.get_minor_ticks())):
                for k, tick in enumerate(ticks):
                    if k >= len(locs) or not lo <= locs[k] <= hi:
                        undrawn |= {id(tick.label1), id(tick.label2)}
                    elif not tick.label2.get_visible() or not getattr(tick, "label2On", True):
                        undrawn.add(id(tick.label2))
    return [t for t in fig.findobj(Text)
            if id(t) not in undrawn and t.get_visible() and t.get_text().strip() and _shown(t, fig)]


def _shown(t: Text, fig) -> bool:
    """Whether a text lies in its figure ``fig`` (the report draws no sub-figures) at all: a label
    pushed off the canvas is not drawn."""
    box = t.get_window_extent(fig.canvas.get_renderer())
    fb = fig.bbox
    return box.x1 > fb.x0 and box.x0 < fb.x1 and box.y1 > fb.y0 and box.y0 < fb.y1 and box.width > 0
