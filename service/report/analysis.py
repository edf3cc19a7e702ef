"""What the report shows, from a result and (optionally) its capture: numbers only, no drawing.

The capture's observations are judged with the result's poses by calib, once
(:func:`wandcal.calib.judge.evaluate.evaluate_capture`: the labelled wand ends, each observation's
residual, the wand's path and lengths); here they are split by camera and put into words.

Everything here is in the result's world frame (``result.world.frame``), metres (or the first
pair's baseline when ``world.scale`` is ``arbitrary``), pixels with the origin top-left, y down.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from wandcal.calib.judge.coverage import coverage_advice, coverage_grid, covered_fraction
from wandcal.calib.judge.evaluate import evaluate_capture
from wandcal.calib.rig import AxisObservations, PointObservations, Rig, WandObservations
from wandcal.calib.run.guidance import DEFAULT_MIN_COVERAGE
from wandcal.capture.folder import Capture, CaptureFormatError
from wandcal.capture.result_file import ResultFile

COVERAGE_GOAL = DEFAULT_MIN_COVERAGE  # the wanding guidance's goal, and the verdict's "excellent"
# Residuals are noise, the same over the whole image, when the lens model fits. A camera's samples
# are split in thirds by their distance from the principal point; the ratio of the outer third's
# median error to the inner third's is 1 +- 1.0/sqrt(n) for Rayleigh-distributed noise (each
# median's relative spread is 0.72/sqrt(n)): 0.1 at n = 100, so 1.5 is five of those, a lens
# error (distortion, principal point), not chance. Measured on a simulated ring: 0.97-1.09 with
# the right lens, 1.3-1.9 with k1 off by 0.25.
EDGE_RATIO = 1.5
MIN_EDGE_SAMPLES = 100  # per third
# A camera with more than this share of its wand observations off by OUTLIER_SIGMAS sees
# something else bright now and then (a reflection, a second marker); a few are ordinary.
OUTLIER_SHARE = 0.05
MAX_FRAMES_NAMED = 5  # frames quoted in one piece of advice


@dataclass(frozen=True, eq=False)
class CameraSummary:
    """One camera's figures and words.

    doc: its entry of the result; uv: (M, 2) raw pixels of its wand ends (capture only);
    residual_px: (M, 2) projected minus observed, pixels; outlier: (M,) bool; point_uv,
    point_residual_px: (Q, 2), point_outlier: (Q,) the same for single-point tracks (outliers
    judged among all the rig's point residuals, as the wand's are); coverage: (rows, cols) counts
    of samples (wand ends and single points) per cell, or None without a capture; advice:
    sentences for the operator.
    """

    index: int
    doc: dict
    uv: np.ndarray
    residual_px: np.ndarray
    outlier: np.ndarray
    point_uv: np.ndarray
    point_residual_px: np.ndarray
    point_outlier: np.ndarray
    coverage: np.ndarray | None
    advice: list[str] = field(default_factory=list)

    @property
    def id(self) -> str:
        return self.doc["id"]

    @property
    def size(self) -> tuple[int, int]:
        """(width, height), pixels."""
        return self.doc["width"], self.doc["height"]

    @property
    def covered(self) -> float | None:
        return None if self.coverage is None else covered_fraction(self.coverage)


@dataclass(frozen=True, eq=False)
class ReportData:
    """The whole report's content.

    trajectory: (T, 3) the wand's midpoint in each frame, world; trajectory_frames: (T,) their
    frame numbers; wand_frames: (F,) frame numbers
    of the frames two cameras saw; wand_length_m: (F,) each end triangulated on its own;
    outlier_frame: (F,) bool, a frame with an outlier observation or a wand length
    OUTLIER_SIGMAS robust sigmas off the median; static_markers:
    (K, 3) or None; axis: {role: (3,)} triangulated axis points; points: (T, 3) single-point
    tracks (easyWand's background points); notes: what could not be drawn, and why.
    """

    result: ResultFile
    cameras: list[CameraSummary]
    has_capture: bool
    trajectory: np.ndarray
    trajectory_frames: np.ndarray
    wand_frames: np.ndarray
    wand_length_m: np.ndarray
    outlier_frame: np.ndarray
    static_markers: np.ndarray | None
    axis: dict
    points: np.ndarray
    notes: list[str]

    @property
    def unit(self) -> str:
        """The length unit of the world frame."""
        return "units" if self.result.doc.get("world", {}).get("scale") == "arbitrary" else "m"

    @property
    def advice(self) -> list[str]:
        return [a for cam in self.cameras for a in cam.advice]


def analyse(result: ResultFile, capture: Capture | None) -> ReportData:
    """Everything the report draws and says; the capture's observations are judged with the result's poses.

    Raises:
        CaptureFormatError: the capture's cameras are not the result's.
    """
    docs = result.doc["cameras"]
    world = result.doc.get("world") or {}
    if capture is None:
        notes = [("The residuals, the coverage maps, the wand length over frames and the wand's path need the "
                  "capture the result came from: run 'wandcal report RESULT --capture CAPTURE --out DIR'.")]
        empty2 = np.zeros((0, 2))
        none = np.zeros(0, bool)
        cams = [CameraSummary(i, d, empty2, empty2, none, empty2, empty2, none, None) for i, d in enumerate(docs)]
        z = np.zeros(0)
        return ReportData(result, cams, False, np.zeros((0, 3)), z.astype(int), z.astype(int), z, z.astype(bool),
                          None, {}, np.zeros((0, 3)), notes)

    rig, wand, points, axis = aligned_observations(result, capture)
    found = evaluate_capture(rig, result.R, result.t, wand, points, axis)
    ev, pts = found.wand, found.points
    notes = [] if ev is not None else ["The capture has no wand: no wand length over frames and no wand path."]
    static = None
    if rig.static_markers is not None:
        if world.get("frame") == "static_object":
            static = rig.static_markers  # the world is the static object's own frame
        else:
            notes.append(f"The static object is not drawn: the result's world frame is {world.get('frame')!r}, "
                         "not the static object's, so where its markers stand is not known.")

    cams = []
    empty2 = np.zeros((0, 2))
    for i, d in enumerate(docs):
        mine = ev.camera == i if ev is not None else np.zeros(0, bool)
        uv = ev.uv[mine] if ev is not None else empty2
        res = ev.residual_px[mine] if ev is not None else empty2
        out = ev.outlier[mine] if ev is not None else np.zeros(0, bool)
        theirs = pts.camera == i
        # every sample that placed the camera, as the result's coverage and verdict count them
        samples = np.vstack([uv, pts.uv[theirs]])
        counts = coverage_grid(samples, d["width"], d["height"]) if ev is not None or len(samples) else None
        cam = CameraSummary(i, d, uv, res, out, pts.uv[theirs], pts.residual_px[theirs], pts.outlier[theirs], counts)
        cams.append(replace(cam, advice=camera_advice(cam, ev.frame[mine] if ev is not None else np.zeros(0, int))))
    frames, length, outlier_frame = found.wand_frames()
    return ReportData(result, cams, True, found.trajectory, found.trajectory_frames, frames, length, outlier_frame,
                      static, found.axis, pts.cloud, notes)


def camera_advice(cam: CameraSummary, frame: np.ndarray) -> list[str]:
    """Words for the operator about one camera: where its image lacks wand samples, whether its
    residuals grow towards the rim, and how often it saw something else than the wand.

    frame: (M,) the frame number of each of ``cam``'s wand observations.
    """
    out = []
    if cam.coverage is not None and cam.coverage.any():
        words = coverage_advice(cam.coverage, cam.id, COVERAGE_GOAL)
        if words and len(cam.point_uv):
            words = words.replace("wand samples", "samples")  # its single points are counted too
        if words:
            out.append(words)
    elif cam.coverage is not None:
        out.append(f"{cam.id}: no wand samples anywhere in its image; wave the wand where {cam.id} and another "
                   "camera both see it")
    err = np.linalg.norm(cam.residual_px, axis=1)
    if len(err):
        ratio = rim_ratio(cam)
        if ratio is not None and ratio > EDGE_RATIO:
            out.append(f"{cam.id}: its residuals grow away from the image centre (the outer third of its samples "
                       f"{ratio:.1f}x the inner third's); its lens distortion or principal point may be off: check "
                       "its intrinsics, or calibrate with --refine-intrinsics focal,principal,k1")
        share = float(np.mean(cam.outlier))
        if share > OUTLIER_SHARE:
            worst = np.unique(frame[cam.outlier][np.argsort(-err[cam.outlier])][:MAX_FRAMES_NAMED])
            out.append(f"{cam.id}: {share:.0%} of its wand observations are outliers (e.g. frames "
                       f"{', '.join(map(str, worst))}); look for reflections or a second bright marker in its view")
    return out


def rim_ratio(cam: CameraSummary) -> float | None:
    """The median error of the outer third of a camera's wand samples (by distance from the
    principal point) over the inner third's, outliers left out; None with fewer than
    :data:`MIN_EDGE_SAMPLES` a third."""
    keep = ~cam.outlier
    err = np.linalg.norm(cam.residual_px[keep], axis=1)
    if len(err) < 3 * MIN_EDGE_SAMPLES:
        return None
    centre = cam.doc["K"][0][2], cam.doc["K"][1][2]
    radius = np.hypot(*(cam.uv[keep] - centre).T)
    inner, outer = np.quantile(radius, [1 / 3, 2 / 3])
    return float(np.median(err[radius > outer]) / max(np.median(err[radius < inner]), 1e-12))


def aligned_observations(result: ResultFile, capture: Capture
             ) -> tuple[Rig, WandObservations, PointObservations | None, AxisObservations | None]:
    """The capture's observations indexed by the result's cameras, and a rig with the result's
    (refined) intrinsics, the capture's wand length and static object."""
    ids, cap_ids = result.rig.ids, capture.rig.ids
    if sorted(ids) != sorted(cap_ids):
        raise CaptureFormatError(
            f"the capture's cameras ({', '.join(cap_ids)}) are not the result's ({', '.join(ids)}); "
            "give the capture the result was calibrated from")
    to_result = np.array([ids.index(c) for c in cap_ids])
    rig = Rig(result.rig.cameras, capture.rig.wand_length or result.rig.wand_length, capture.rig.static_markers)
    wand = capture.wand
    wand = WandObservations(wand.frame, to_result[wand.camera.astype(int)], wand.uv) if len(wand) else wand
    points = capture.points
    if points is not None and len(points):
        points = PointObservations(points.frame, to_result[points.camera.astype(int)], points.uv, points.point)
    axis = capture.axis
    if axis is not None and len(axis.role):
        axis = AxisObservations(role=axis.role, camera=to_result[axis.camera.astype(int)], uv=axis.uv)
    for cam in result.rig.cameras:
        given = capture.rig.cameras[cap_ids.index(cam.id)]
        if (given.width, given.height) != (cam.width, cam.height):
            raise CaptureFormatError(
                f"camera {cam.id!r}: the capture's images are {given.width}x{given.height} px, the result's "
                f"{cam.width}x{cam.height}; give the capture the result was calibrated from")
    return rig, wand, points, axis
