"""The look every report figure shares: the canvas (matplotlib's Agg, off screen, a PNG of a fixed
size), the cameras' colours and the colours the page's captions name.

No pyplot: each figure is its own ``Figure`` on its own ``FigureCanvasAgg``, so the service can
draw reports from several threads at once and nothing touches a display.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

DPI = 100
HIST_BINS = 40
CAMERA_COLOURS = "tab10"  # one colour per camera, the same in every figure
# (colour, its name in the captions) of the rig's samples: service/report/page.py words the
# caption from these, so a caption cannot name a colour the figure does not draw
WAND_DOTS = ("#566573", "blue-grey")
POINT_DOTS = ("#e67e22", "orange")
AXIS_POINTS = ("#8e44ad", "purple")
OUTLIER_CROSSES = ("#1f77b4", "blue")
FRAME_DOTS = ("#2c6fbb", "blue")  # the wand figure's frames


def camera_colour(index: int):
    """The camera's colour: the same in the rig and on its own figure."""
    cmap = colormaps[CAMERA_COLOURS]
    return cmap(index % cmap.N)


def new_figure(size_px: tuple[int, int], layout: Literal["constrained", "tight"] | None = "constrained") -> Figure:
    """A figure of ``size_px`` (width, height) pixels on its own Agg canvas."""
    fig = Figure(figsize=(size_px[0] / DPI, size_px[1] / DPI), dpi=DPI, layout=layout)
    FigureCanvasAgg(fig)
    return fig


def save_png(fig: Figure, path: Path) -> Path:
    fig.savefig(path, dpi=DPI, format="png")  # no bbox_inches="tight": the size stays the one asked for
    return path
