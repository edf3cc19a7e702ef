"""The report's figures, drawn off screen with matplotlib's Agg canvas, each a PNG of a fixed size.

No pyplot: each figure is its own ``Figure`` on its own ``FigureCanvasAgg``, so the service can
draw reports from several threads at once and nothing touches a display.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d import Axes3D, proj3d  # importing it registers the "3d" projection

from wandcal.calib.judge.coverage import GRID
from wandcal.calib.judge.quality import HIGH_RMS_PX, OUTLIER_SIGMAS
from wandcal.calib.observations import robust_sigma
from wandcal.service.report.analysis import CameraSummary, ReportData
from wandcal.service.report.labels import Label, axes_of, hide_colliding_ticks, place_labels

DPI = 100
# (width, height) in pixels: wide enough for a laptop screen, readable when the page scales them down
RIG_SIZE_PX = (1500, 720)
CAMERA_SIZE_PX = (1500, 470)
WAND_SIZE_PX = (1500, 450)
FRUSTUM_DEPTH = 0.12  # of the scene's extent: big enough to see where a camera looks, small enough not to clutter
AXIS_LENGTH = 0.15  # of the scene's extent: the world axes drawn at the origin
MIN_SPAN = 0.15  # of the extent: a flat scene (all cameras at one height) still gets a visible third axis
ARROW_CELL_FILL = 0.8  # a mean residual of HIGH_RMS_PX (or the largest, if larger) spans this share of a cell
MIN_ARROW_SAMPLES = 3  # a cell's mean residual over fewer samples is noise, not a pattern
HIST_BINS = 40
CAMERA_COLOURS = "tab10"  # one colour per camera, the same in every figure
AXIS_COLOURS = {"x": "#c0392b", "y": "#27ae60", "z": "#2c6fbb"}  # red, green, blue as in every 3D tool
EMPTY_CELL = "#f4c7c3"  # a pale red: an empty cell is what the operator should act on
AXIS_LABEL_PAD = 10  # points: a 3D axis's name clear of its tick numbers (matplotlib's 4 puts them on one another)
TEXT_BOX = {"facecolor": "white", "alpha": 0.75, "edgecolor": "none", "pad": 1.5}
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


def _figure(size_px: tuple[int, int], layout: Literal["constrained", "tight"] | None = "constrained") -> Figure:
    fig = Figure(figsize=(size_px[0] / DPI, size_px[1] / DPI), dpi=DPI, layout=layout)
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Figure, path: Path) -> Path:
    fig.savefig(path, dpi=DPI, format="png")  # no bbox_inches="tight": the size stays the one asked for
    return path


# -- the rig ----------------------------------------------------------------------------------
def frustum(doc: dict, depth: float) -> np.ndarray:
    """(5, 3) a camera's centre and its image corners (top-left, top-right, bottom-right,
    bottom-left) pushed out to ``depth`` along its optical axis, world coordinates."""
    K, R, t = np.array(doc["K"]), np.array(doc["R"]), np.array(doc["t"])
    w, h = doc["width"], doc["height"]
    corners = np.array([[0, 0, 1], [w, 0, 1], [w, h, 1], [0, h, 1]], float)
    rays = corners @ np.linalg.inv(K).T * depth  # camera frame, z = depth
    centre = -R.T @ t
    return np.vstack([centre, rays @ R + centre])  # x_world = R^T x_cam + centre


def display_axes(world_frame: str | None) -> tuple[np.ndarray, tuple[str, str, str]]:
    """(3, 3) rotation from world to drawing coordinates, and the drawn axes' names.

    A static object or axis points give a z-up world, drawn as it is. The first camera's frame
    (world frame ``camera``) has y pointing down its image and z along its view: it is drawn with
    -y up and looked at from above along -y, as the scene stands when that camera is level.
    """
    if world_frame == "camera":
        return np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]), ("x", "z", "−y")
    return np.eye(3), ("x", "y", "z")


def _scene_extent(data: ReportData, centres: np.ndarray, M: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(3,) low and high corners of everything drawn (drawing coordinates, ``M @ world``), and the
    extent (the box's diagonal)."""
    parts = [centres, np.zeros((1, 3)), data.trajectory, data.points]
    if data.static_markers is not None:
        parts.append(data.static_markers)
    pts = np.vstack([p for p in parts if len(p)]) @ M.T
    centres = centres @ M.T
    lo, hi = np.percentile(pts, 1, axis=0), np.percentile(pts, 99, axis=0)  # a stray point does not shrink the rig
    lo, hi = np.minimum(lo, centres.min(0)), np.maximum(hi, centres.max(0))
    extent = float(np.linalg.norm(hi - lo)) or 1.0
    return lo, hi, extent


def rig_figure(data: ReportData, path: Path) -> Path:
    return _save(draw_rig(data), path)


def draw_rig(data: ReportData) -> Figure:
    """The rig in 3D and from above: cameras as frusta with their ids, the wand's path, the static
    object, axis points, single-point tracks and the world axes. Labels placed apart
    (:func:`wandcal.service.report.labels.place_labels`)."""
    docs = data.result.doc["cameras"]
    world = data.result.doc.get("world") or {}
    M, names = display_axes(world.get("frame"))
    centres = np.array([d["center"] for d in docs])
    lo, hi, extent = _scene_extent(data, centres, M)
    depth = FRUSTUM_DEPTH * extent
    frusta = [frustum(d, depth) for d in docs]
    fig = _figure(RIG_SIZE_PX, layout=None)  # constrained layout squeezes 3D axes: placed by hand
    ax3 = fig.add_axes((0.0, 0.04, 0.50, 0.9), projection="3d")  # room below for the x axis's name
    assert isinstance(ax3, Axes3D)  # what projection="3d" makes; the type checker sees Axes
    top = fig.add_axes((0.59, 0.2, 0.36, 0.72))
    unit = data.unit
    labels = {ax: _draw_scene(ax, dims, M, data, docs, frusta, extent) for ax, dims in ((ax3, (0, 1, 2)), (top, (0, 1)))}
    # equal scale on every axis, with some room for the labels
    pad = 0.08 * extent
    frusta_pts = np.vstack(frusta) @ M.T
    lo, hi = np.minimum(lo, frusta_pts.min(0)) - pad, np.maximum(hi, frusta_pts.max(0)) + pad
    span = np.maximum(hi - lo, MIN_SPAN * extent)
    mid = (hi + lo) / 2
    lo, hi = mid - span / 2, mid + span / 2
    ax3.set_xlim(lo[0], hi[0])
    ax3.set_ylim(lo[1], hi[1])
    ax3.set_zlim(lo[2], hi[2])
    ax3.set_box_aspect(tuple(span))
    ax3.set_xlabel(f"{names[0]} ({unit})")
    ax3.set_ylabel(f"{names[1]} ({unit})")
    ax3.set_zlabel(f"{names[2]} ({unit})")
    ax3.view_init(elev=25, azim=-60)
    title = fig.text(0.25, 0.96, f"the rig in 3D (world frame: {world.get('frame', '?')})", ha="center", va="top",
                     fontsize=12)
    top.set_aspect("equal")
    top.set_xlim(lo[0], hi[0])
    top.set_ylim(lo[1], hi[1])
    top.set_xlabel(f"{names[0]} ({unit})")
    top.set_ylabel(f"{names[1]} ({unit})")
    top.grid(True, alpha=0.3)
    top.set_title("from above (looking down the z axis)" if world.get("frame") != "camera" else
                  f"from above if {docs[0]['id']} is level (looking along its y axis)")
    handles, legend_labels = top.get_legend_handles_labels()
    if handles:
        top.legend(handles, legend_labels, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncols=2, fontsize=9,
                   frameon=False, markerscale=2)
    for axis in axes_of(ax3):
        axis.labelpad = AXIS_LABEL_PAD
    hide_colliding_ticks(fig, [ax3, top])  # draws the figure: the 3D projection and every text's place are known
    for ax, wanted in labels.items():
        fixed = [title, ax.title, *(a.label for a in axes_of(ax)),
                 *(t.label1 for a in axes_of(ax) for t in a.get_major_ticks())]
        place_labels(ax, [Label(text, _projected(ax, point), style) for text, point, style in wanted], fixed)
    return fig


def _projected(ax, point: np.ndarray) -> tuple[float, float]:
    """Where a drawing-space point lands in the axes' 2D data coordinates (a 3D axes' projection)."""
    if not hasattr(ax, "zaxis"):
        return float(point[0]), float(point[1])
    x, y, _ = proj3d.proj_transform(*point, ax.get_proj())
    return float(x), float(y)


def _draw_scene(ax, dims: tuple[int, ...], M: np.ndarray, data: ReportData, docs: list[dict],
                frusta: list[np.ndarray], extent: float) -> list[tuple[str, np.ndarray, dict]]:
    """Draw the rig's elements (world coordinates, drawn as ``M @ x``) on a 3D axes (dims 0, 1, 2)
    or a top view (dims 0, 1); return the labels to place, (text, drawing-space point, style),
    cameras first."""
    sel = list(dims)

    def xy(points):
        points = np.atleast_2d(points) @ M.T
        return [points[:, d] for d in sel]

    if len(data.trajectory):
        ax.scatter(*xy(data.trajectory), s=4, c=WAND_DOTS[0], alpha=0.45, linewidths=0,
                   label=f"wand midpoints ({len(data.trajectory)} frames)")
    if len(data.points):
        ax.scatter(*xy(data.points), s=4, c=POINT_DOTS[0], alpha=0.5, linewidths=0,
                   label=f"single-point tracks ({len(data.points)})")
    if data.static_markers is not None:
        ax.scatter(*xy(data.static_markers), s=36, c="black", marker="s", label="static object markers")
    cameras, others = [], []
    for role, p in data.axis.items():
        ax.scatter(*xy(p), s=40, c=AXIS_POINTS[0], marker="D")
        others.append((str(role), M @ p, {"color": AXIS_POINTS[0], "fontsize": 10, "bbox": TEXT_BOX}))
    length = AXIS_LENGTH * extent
    for k, name in enumerate("xyz"):
        tip = np.zeros(3)
        tip[k] = length
        if len(sel) == 3 or abs(M[2, k]) < 0.5:  # an axis pointing at the viewer is a dot: left out
            seg = np.vstack([np.zeros(3), tip])
            ax.plot(*xy(seg), color=AXIS_COLOURS[name], linewidth=2.5)
            others.append((name, M @ tip, {"color": AXIS_COLOURS[name], "fontsize": 12, "fontweight": "bold",
                                           "bbox": TEXT_BOX}))
    for i, (doc, f) in enumerate(zip(docs, frusta)):
        colour = camera_colour(i)
        apex, corners = f[0], f[1:]
        for c in corners:
            ax.plot(*xy(np.vstack([apex, c])), color=colour, linewidth=1)
        ring = np.vstack([corners, corners[:1]])
        ax.plot(*xy(ring), color=colour, linewidth=1)
        ax.plot(*xy(corners[:2]), color=colour, linewidth=3.5)  # the image's top edge: which way is up
        ax.scatter(*xy(apex), s=25, color=colour)
        cameras.append((doc["id"], M @ apex, {"color": "black", "fontsize": 11, "fontweight": "bold",
                                              "bbox": TEXT_BOX | {"edgecolor": colour}, "zorder": 10}))
    if len(sel) == 2:
        ax.plot([], [], color="gray", linewidth=1, label="camera frustum (thick edge: image top)")
    return cameras + others


# -- one camera -------------------------------------------------------------------------------
def camera_figure(cam: CameraSummary, path: Path) -> Path:
    return _save(draw_camera(cam), path)


def draw_camera(cam: CameraSummary) -> Figure:
    """Three panels of one camera: where it saw the wand (a grid of counts, empty cells pale red),
    its residuals over the image (RMS per cell, arrows of the mean residual), their histogram."""
    fig = _figure(CAMERA_SIZE_PX)
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


# -- the wand ---------------------------------------------------------------------------------
def wand_figure(data: ReportData, path: Path) -> Path:
    return _save(draw_wand(data), path)


def draw_wand(data: ReportData) -> Figure:
    """The wand's length over the frames (each end triangulated on its own), outlier frames as red
    crosses (pinned to the plot's edge when far off), the nominal length as a line; and the
    lengths' histogram beside it."""
    fig = _figure(WAND_SIZE_PX)
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
