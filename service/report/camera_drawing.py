"""The report's figure of one camera: where it saw the wand, its residuals over the image and
their histogram."""

from __future__ import annotations

import numpy as np
from matplotlib import colormaps
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from wandcal.calib.judge.coverage import GRID
from wandcal.calib.judge.quality import HIGH_RMS_PX, OUTLIER_SIGMAS
from wandcal.calib.observations import robust_sigma
from wandcal.service.report.analysis import CameraSummary
from wandcal.service.report.figure_style import HIST_BINS, OUTLIER_CROSSES, camera_colour, new_figure

# (width, height) in pixels: wide enough for a laptop screen, readable when the page scales them down
CAMERA_SIZE_PX = (1500, 470)
ARROW_CELL_FILL = 0.8  # a mean residual of HIGH_RMS_PX (or the largest, if larger) spans this share of a cell
MIN_ARROW_SAMPLES = 3  # a cell's mean residual over fewer samples is noise, not a pattern
EMPTY_CELL = "#f4c7c3"  # a pale red: an empty cell is what the operator should act on


def draw_camera(cam: CameraSummary) -> Figure:
    """Three panels of one camera: where it saw the wand (a grid of counts, empty cells pale red),
    its residuals over the image (RMS per cell, arrows of the mean residual), their histogram."""
    fig = new_figure(CAMERA_SIZE_PX)
    axes = fig.subplots(1, 3, width_ratios=[1, 1, 0.9])
    fig.suptitle(cam.id, fontsize=14, fontweight="bold", color=camera_colour(cam.index))
    _coverage_panel(fig, axes[0], cam)
    _residual_map_panel(fig, axes[1], cam)
    _histogram_panel(axes[2], cam)
    return fig


def _image_axes(ax, cam: CameraSummary) -> None:
    w, h = cam.size
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)  # pixel origin top-left, y down, as the camera sees it
    ax.set_aspect("equal")
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    rows, cols = GRID
    ax.set_xticks(np.linspace(0, w, cols + 1)[::2])
    ax.set_yticks(np.linspace(0, h, rows + 1)[::2])


def _coverage_panel(fig: Figure, ax, cam: CameraSummary) -> None:
    _image_axes(ax, cam)
    w, h = cam.size
    # no grid for a camera with nothing that placed it (no wand evidence, no points): every cell empty
    counts = cam.coverage if cam.coverage is not None else np.zeros(GRID, dtype=np.int64)
    shown = np.ma.masked_less(counts, 1)
    cmap = _cmap("viridis", EMPTY_CELL)
    im = ax.imshow(shown, extent=(0, w, h, 0), cmap=cmap, norm=Normalize(0, max(1, counts.max())),
                   interpolation="nearest")
    what = "samples per cell (wand ends and single points)" if len(cam.point_uv) else "wand ends seen per cell"
    bar = fig.colorbar(im, ax=ax, shrink=0.85, label=what)
    bar.locator = MaxNLocator(integer=True)
    bar.update_ticks()
    if len(cam.uv):
        ax.scatter(cam.uv[:, 0], cam.uv[:, 1], s=2, c="white", alpha=0.6, linewidths=0)
    if len(cam.point_uv):
        ax.scatter(cam.point_uv[:, 0], cam.point_uv[:, 1], s=3, c="#e67e22", alpha=0.8, linewidths=0)
        ax.set_xlabel("u (px); white: wand ends, orange: single points")
    _cell_lines(ax, cam)
    ax.set_title(f"coverage: {cam.covered or 0.0:.0%} of the cells (pale red: none)", fontsize=11)


def _residual_map_panel(fig: Figure, ax, cam: CameraSummary) -> None:
    _image_axes(ax, cam)
    bad = np.concatenate([cam.outlier, cam.point_outlier])
    uv_all = np.vstack([cam.uv, cam.point_uv])
    uv, res = uv_all[~bad], np.vstack([cam.residual_px, cam.point_residual_px])[~bad]
    if not len(uv):
        ax.text(0.5, 0.5, "no observations", transform=ax.transAxes, ha="center", va="center")
        ax.set_title("residuals over the image", fontsize=11)
        return
    w, h = cam.size
    rows, cols = GRID
    r = np.clip((uv[:, 1] * rows / h).astype(int), 0, rows - 1)
    c = np.clip((uv[:, 0] * cols / w).astype(int), 0, cols - 1)
    cell = r * cols + c
    n = np.bincount(cell, minlength=rows * cols)
    sq = np.bincount(cell, np.sum(res**2, axis=1), minlength=rows * cols)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(sq / n).reshape(rows, cols)
        mean = np.stack([np.bincount(cell, res[:, k], minlength=rows * cols) / n for k in (0, 1)], axis=1)
    # colours on an absolute scale up to HIGH_RMS_PX (the result's warning level): blob noise is
    # pale, an error a warning would name is dark red
    im = ax.imshow(np.ma.masked_invalid(rms), extent=(0, w, h, 0), cmap=_cmap("YlOrRd", "#eeeeee"),
                   norm=Normalize(0, max(HIGH_RMS_PX, float(np.nanmax(rms)))), interpolation="nearest")
    fig.colorbar(im, ax=ax, shrink=0.85, label="RMS residual per cell (px)")
    ok = n >= MIN_ARROW_SAMPLES
    centres_u = (np.arange(rows * cols) % cols + 0.5) * w / cols
    centres_v = (np.arange(rows * cols) // cols + 0.5) * h / rows
    biggest = float(np.max(np.linalg.norm(mean[ok], axis=1))) if ok.any() else 0.0
    reference = max(HIGH_RMS_PX, biggest)
    gain = ARROW_CELL_FILL * min(w / cols, h / rows) / reference  # image px per residual px
    q = ax.quiver(centres_u[ok], centres_v[ok], mean[ok, 0], mean[ok, 1], angles="xy", scale_units="xy",
                  scale=1 / gain, color="black", width=0.006)
    key = _round_down(reference)
    ax.quiverkey(q, 0.97, 1.04, key, f"mean residual {key:g} px", labelpos="W", coordinates="axes",
                 fontproperties={"size": 9})
    if bad.any():
        ax.scatter(uv_all[bad, 0], uv_all[bad, 1], marker="x", s=30, c=OUTLIER_CROSSES[0], linewidths=1.5)
        ax.set_xlabel(f"u (px); \u00d7: {int(bad.sum())} outliers, left out of the cells")
    ax.set_title("residuals", fontsize=11, loc="left")


def histogram_rms(cam: CameraSummary, inliers: np.ndarray) -> tuple[float, str]:
    """The histogram's dashed line and its label: the camera's reprojection RMS as the result
    gives it (the page's table, the command line's ``rms px``: its wand ends the solve kept); a
    result without one (points only) shows the RMS of the histogram's own inliers, so labelled."""
    rms = cam.doc.get("reprojection_rms_px")
    if rms is not None:
        return float(rms), f"reprojection RMS {rms:.2f} px (wand ends the solve kept)"
    own = float(np.sqrt(np.mean(inliers**2))) if len(inliers) else float("nan")
    return own, f"RMS of the residuals without outliers {own:.2f} px"


def _histogram_panel(ax, cam: CameraSummary) -> None:
    wand = np.linalg.norm(cam.residual_px, axis=1)
    pts = np.linalg.norm(cam.point_residual_px, axis=1)
    bad = np.concatenate([cam.outlier, cam.point_outlier])
    both = np.concatenate([wand, pts])
    ax.set_xlabel("reprojection error (px)")
    ax.set_ylabel("observations")
    if not len(both):
        ax.text(0.5, 0.5, "no observations", transform=ax.transAxes, ha="center", va="center")
        return
    inliers = both[~bad]
    sigma = robust_sigma(inliers if len(inliers) else both)
    top = max(np.percentile(inliers, 99) if len(inliers) else 0.0, OUTLIER_SIGMAS * sigma, 1e-3)
    bins = np.linspace(0, top, HIST_BINS + 1)
    series = [(wand[~cam.outlier], "wand ends", "#2c6fbb"), (pts[~cam.point_outlier], "single points", "#e67e22"),
              (both[bad], "outliers", "#c0392b")]
    series = [(np.clip(v, 0, top), label, colour) for v, label, colour in series if len(v)]
    ax.hist([v for v, _, _ in series], bins=bins, stacked=True, label=[lb for _, lb, _ in series],
            color=[c for _, _, c in series])
    r = np.linspace(0, top, 200)
    rayleigh = r / sigma**2 * np.exp(-(r**2) / (2 * sigma**2))  # the error radius of 2D Gaussian noise
    ax.plot(r, len(inliers) * (bins[1] - bins[0]) * rayleigh, color="black", linewidth=1.2,
            label=f"Gaussian noise, \u03c3 = {sigma:.2f} px")
    rms, label = histogram_rms(cam, inliers)
    ax.axvline(rms, color="#555555", linestyle="--", linewidth=1, label=label)
    ax.set_xlim(0, top)
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.legend(fontsize=8)
    ax.set_title(f"{len(both)} residuals (last bin: \u2265 {top:.2f} px)", fontsize=11)


def _cell_lines(ax, cam: CameraSummary) -> None:
    w, h = cam.size
    rows, cols = GRID
    for x in np.linspace(0, w, cols + 1):
        ax.axvline(x, color="white", linewidth=0.5, alpha=0.7)
    for y in np.linspace(0, h, rows + 1):
        ax.axhline(y, color="white", linewidth=0.5, alpha=0.7)


def _cmap(name: str, bad: str):
    """A copy of a colour map showing masked cells (no samples) in ``bad``."""
    return colormaps[name].with_extremes(bad=bad)


def _round_down(x: float) -> float:
    """The largest 1, 2 or 5 times a power of ten not above ``x`` (a readable arrow key)."""
    if x <= 0:
        return 1.0
    p = 10 ** np.floor(np.log10(x))
    return float(max(m * p for m in (1, 2, 5) if m * p <= x))
