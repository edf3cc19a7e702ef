"""The report's rig figure: the cameras as frusta with their ids, the wand's path, the static
object, axis points, single-point tracks and the world axes, in 3D and from above."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from mpl_toolkits.mplot3d import Axes3D, proj3d  # importing it registers the "3d" projection

from wandcal.service.report.analysis import ReportData
from wandcal.service.report.figure_style import AXIS_POINTS, POINT_DOTS, WAND_DOTS, camera_colour, new_figure
from wandcal.service.report.labels import Label, axes_of, hide_colliding_ticks, place_labels

# (width, height) in pixels: wide enough for a laptop screen, readable when the page scales them down
RIG_SIZE_PX = (1500, 720)
FRUSTUM_DEPTH = 0.12  # of the scene's extent: big enough to see where a camera looks, small enough not to clutter
AXIS_LENGTH = 0.15  # of the scene's extent: the world axes drawn at the origin
MIN_SPAN = 0.15  # of the extent: a flat scene (all cameras at one height) still gets a visible third axis
AXIS_COLOURS = {"x": "#c0392b", "y": "#27ae60", "z": "#2c6fbb"}  # red, green, blue as in every 3D tool
AXIS_LABEL_PAD = 10  # points: a 3D axis's name clear of its tick numbers (matplotlib's 4 puts them on one another)
TEXT_BOX = {"facecolor": "white", "alpha": 0.75, "edgecolor": "none", "pad": 1.5}


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
    fig = new_figure(RIG_SIZE_PX, layout=None)  # constrained layout squeezes 3D axes: placed by hand
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


