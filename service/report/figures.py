"""The report's figures, each a PNG of a fixed size: the rig (:mod:`wandcal.service.report.rig_drawing`),
each camera (:mod:`wandcal.service.report.camera_drawing`) and the wand's length, drawn here; their
shared look in :mod:`wandcal.service.report.figure_style`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from wandcal.service.report.analysis import CameraSummary, ReportData
from wandcal.service.report.camera_drawing import CAMERA_SIZE_PX, draw_camera, histogram_rms
from wandcal.service.report.figure_style import (
    AXIS_POINTS,
    FRAME_DOTS,
    HIST_BINS,
    OUTLIER_CROSSES,
    POINT_DOTS,
    WAND_DOTS,
    camera_colour,
    new_figure,
    save_png,
)
from wandcal.service.report.rig_drawing import RIG_SIZE_PX, draw_rig, frustum

# what callers took from this module before the rig and camera figures had modules of their own
__all__ = ["AXIS_POINTS", "CAMERA_SIZE_PX", "FRAME_DOTS", "OUTLIER_CROSSES", "POINT_DOTS", "RIG_SIZE_PX", "WAND_DOTS",
           "WAND_SIZE_PX", "camera_colour", "camera_figure", "draw_camera", "draw_rig", "draw_wand", "frustum",
           "histogram_rms", "rig_figure", "wand_figure"]

# (width, height) in pixels: wide enough for a laptop screen, readable when the page scales them down
WAND_SIZE_PX = (1500, 450)


def rig_figure(data: ReportData, path: Path) -> Path:
    return save_png(draw_rig(data), path)


def camera_figure(cam: CameraSummary, path: Path) -> Path:
    return save_png(draw_camera(cam), path)


def wand_figure(data: ReportData, path: Path) -> Path:
    return save_png(draw_wand(data), path)


def draw_wand(data: ReportData) -> Figure:
    """The wand's length over the frames (each end triangulated on its own), outlier frames as red
    crosses (pinned to the plot's edge when far off), the nominal length as a line; and the
    lengths' histogram beside it."""
    fig = new_figure(WAND_SIZE_PX)
    ax, side = fig.subplots(1, 2, width_ratios=[4, 1], sharey=True)
    mm = 1000 * data.wand_length_m
    bad = data.outlier_frame
    good = mm[~bad] if (~bad).sum() > 1 else mm
    lo, hi = np.percentile(good, [0.5, 99.5])
    pad = max(hi - lo, 1e-3) * 0.6
    ymin, ymax = lo - pad, hi + pad
    shown = np.clip(mm, ymin, ymax)  # a frame far off still shows, at the edge
    ax.scatter(data.wand_frames[~bad], shown[~bad], s=10, c=FRAME_DOTS[0], linewidths=0, label="frames")
    if bad.any():
        label: str | None = f"outlier frames ({int(bad.sum())}; \u25b2\u25bc: off the scale)"
        for marker, sel in (("x", (mm >= ymin) & (mm <= ymax)), ("^", mm > ymax), ("v", mm < ymin)):
            if (bad & sel).any():
                ax.scatter(data.wand_frames[bad & sel], shown[bad & sel], s=30, marker=marker, c="#c0392b",
                           linewidths=1.5, label=label, clip_on=False)
                label = None
    nominal = (data.result.doc.get("wand") or {}).get("length_m")
    if nominal:
        for a in (ax, side):
            a.axhline(1000 * nominal, color="black", linewidth=1, linestyle="--",
                      label=f"nominal {1000 * nominal:.1f} mm")
    side.hist(shown, bins=HIST_BINS, range=(ymin, ymax), orientation="horizontal", color=FRAME_DOTS[0])
    ax.set_ylim(ymin, ymax)
    ax.set_xlabel("frame")
    ax.set_ylabel("wand length (mm)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right", fontsize=9)
    side.set_xlabel("frames")
    side.grid(True, alpha=0.3)
    mean, std = float(np.mean(good)), float(np.std(good))
    ax.set_title(f"wand length, each end triangulated on its own: {mean:.2f} \u00b1 {std:.2f} mm over "
                 f"{int((~bad).sum())} frames without outliers ({100 * std / mean:.3f}%)", fontsize=11)
    return fig
