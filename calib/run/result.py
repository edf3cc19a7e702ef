"""A calibration's result as typed values, and the ``wandcal-result/1`` document both ways.

:class:`CalibrationResult` holds the poses and the figures a calibration gives: each camera's
(:class:`CameraFigures`), the wand's (:class:`WandReport`), the solver's (:class:`SolverReport`)
and the world frame's (:class:`WorldFrame`). :meth:`CalibrationResult.to_json` writes the
document (docs/result-format.md) and :func:`result_from_json` reads one back. Pure computation:
the file, and the checks that name a bad field, are :mod:`wandcal.capture.result_file`'s.

The document's keys keep the order the code before these types wrote them in (a test compares
the bytes, tests/calib/test_result_format.py): each group of optional keys is written when its
value is there, and absent otherwise, as before. A field a reader of an older result does not
find reads as None.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from wandcal.calib.geometry import camera_centers
from wandcal.calib.rig import Rig

RESULT_FORMAT = "wandcal-result/1"
Json = dict[str, Any]


@dataclass(frozen=True)
class WorstFrame:
    """A frame where the camera's wand residual was among its largest: frame number, pixels."""

    frame: int
    error_px: float


@dataclass(frozen=True)
class PointFigures:
    """A camera's single-point-track observations (points.csv): their count and RMS, pixels
    (None with no observation)."""

    observations: int | None
    rms_px: float | None


@dataclass(frozen=True)
class GeometryUncertainty:
    """A camera's uncertainty apart from the world frame's placement
    (:func:`wandcal.calib.solve.gauge_free.split_uncertainty`): the centre's in world units and in
    mm (None without a scale), the rotation's in degrees."""

    std: float | None
    std_mm: float | None
    rotation_std_deg: float | None


@dataclass(frozen=True)
class PoseUncertainty:
    """A camera's pose uncertainty in the world frame: centre in mm (None without a scale),
    rotation in degrees; ``geometry`` the part apart from the frame's placement (None from a
    re-solve of a few cameras, which does not split it)."""

    center_std_mm: float | None
    rotation_std_deg: float | None
    geometry: GeometryUncertainty | None = None


@dataclass(frozen=True)
class RefinedIntrinsics:
    """A camera's refined intrinsics (``refined``: "focal", "principal", "k1" in the order refined)
    with their standard errors: focal and principal point in pixels, k1 unitless. A value of
    an intrinsic not refined is None."""

    refined: tuple[str, ...]
    focal_px: float | None = None
    focal_std_px: float | None = None
    principal_px: tuple[float, ...] | None = None
    principal_std_px: tuple[float, ...] | None = None
    k1: float | None = None
    k1_std: float | None = None

    _KEYS = {"focal": ("focal_px", "focal_std_px"), "principal": ("principal_px", "principal_std_px"),
             "k1": ("k1", "k1_std")}

    def to_json(self) -> Json:
        out: Json = {"refined": list(self.refined)}
        for name in self.refined:
            for key in self._KEYS.get(name, ()):
                value = getattr(self, key)
                out[key] = list(value) if isinstance(value, tuple) else value
        return out

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> RefinedIntrinsics:
        def vector(value: Any) -> Any:
            return tuple(value) if isinstance(value, list) else value

        return cls(tuple(doc.get("refined") or ()), doc.get("focal_px"), doc.get("focal_std_px"),
                   vector(doc.get("principal_px")), vector(doc.get("principal_std_px")), doc.get("k1"), doc.get("k1_std"))


@dataclass(frozen=True)
class JudgedFigures:
    """A camera judged on the same observations for every method (:mod:`wandcal.calib.run.judgement`):
    ``coverage`` the share of its image's grid with samples and ``uncovered`` the empty parts in
    words; ``noise_px`` its blob noise, ``outlier_share`` of its camera-frames gross outliers,
    ``residual_mm`` and ``ray_mrad`` its residual in space and as an angle; ``residual_of_volume``
    and ``geometry_of_volume`` its ray distance and geometry uncertainty as shares of the volume's
    size (None without a scale)."""

    coverage: float | None
    uncovered: tuple[str, ...] | None
    noise_px: float | None
    outlier_share: float | None
    residual_mm: float | None
    ray_mrad: float | None
    residual_of_volume: float | None
    geometry_of_volume: float | None

    KEYS = ("coverage", "uncovered", "noise_px", "outlier_share", "residual_mm", "ray_mrad", "residual_of_volume",
            "geometry_of_volume")


@dataclass(frozen=True)
class FocalLimitFigures:
    """How far a camera's position hinges on a focal length that was given, not refined
    (:mod:`wandcal.calib.judge.intrinsic_limits`): ``focal_limit`` its figures (mm per 1%, the
    sigma assumed and its source, the data's own), ``honest_std_mm`` the geometry sigma with the
    focal length's (``honest_std`` in the result's units without a scale)."""

    focal_limit: Mapping[str, Any]
    honest_std_mm: float | None = None
    honest_std: float | None = None

    def to_json(self) -> Json:
        out: Json = {"focal_limit": dict(self.focal_limit)}
        if self.honest_std_mm is not None:
            out["geometry_std_honest_mm"] = self.honest_std_mm
        if self.honest_std is not None:
            out["geometry_std_honest"] = self.honest_std
        return out

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> FocalLimitFigures:
        return cls(doc["focal_limit"], doc.get("geometry_std_honest_mm"), doc.get("geometry_std_honest"))


@dataclass(frozen=True)
class Movement:
    """A camera that moved during the capture (:mod:`wandcal.calib.judge.faults.own_errors`): after
    capture frame ``frame`` it is turned by ``degrees`` (+- ``degrees_std``) against its pose
    before, its centre ``centre_mm`` (+- ``centre_std_mm``) away. The pose in the result is a
    compromise of the two: re-solve the camera from the frames after, or calibrate again."""

    frame: int
    degrees: float
    degrees_std: float
    centre_mm: float | None = None
    centre_std_mm: float | None = None

    KEYS = ("frame", "degrees", "degrees_std", "centre_mm", "centre_std_mm")

    def to_json(self) -> Json:
        return {key: getattr(self, key) for key in self.KEYS}

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> Movement:
        return cls(int(doc["frame"]), float(doc["degrees"]), float(doc["degrees_std"]), doc.get("centre_mm"),
                   doc.get("centre_std_mm"))


@dataclass(frozen=True)
class CameraFigures:
    """One camera's figures in a result, beside its pose and intrinsics.

    reprojection_rms_px: its wand ends' RMS residual, pixels (None without a wand observation);
    observations, frames_with_both_ends: its wand observations and camera-frames; worst_frames:
    the largest residuals; initial_pose: what placed it at the start. The groups after them are
    None where the calibration did not make them: ``points`` (point tracks), ``uncertainty`` (a
    covariance), ``intrinsics`` (--refine-intrinsics), ``warnings`` (every warning about it in
    full), ``judged`` and ``verdict`` (the judgement: {"level", "reasons", "advice"},
    :func:`wandcal.calib.judge.verdict.camera_verdict`), ``moved`` (the judgement found it moved
    during the capture; results written before it have none).
    """

    reprojection_rms_px: float | None
    observations: int | None
    frames_with_both_ends: int | None
    worst_frames: tuple[WorstFrame, ...]
    initial_pose: str | None
    points: PointFigures | None = None
    uncertainty: PoseUncertainty | None = None
    intrinsics: RefinedIntrinsics | None = None
    warnings: tuple[str, ...] | None = None
    judged: JudgedFigures | None = None
    verdict: Mapping[str, Any] | None = None
    focal_limit: FocalLimitFigures | None = None
    moved: Movement | None = None

    def to_json(self) -> Json:
        out: Json = {"reprojection_rms_px": self.reprojection_rms_px, "observations": self.observations,
                     "frames_with_both_ends": self.frames_with_both_ends,
                     "worst_frames": [{"frame": w.frame, "error_px": w.error_px} for w in self.worst_frames],
                     "initial_pose": self.initial_pose}
        if self.points is not None:
            out |= {"point_observations": self.points.observations, "point_rms_px": self.points.rms_px}
        if self.uncertainty is not None:
            u = self.uncertainty
            out |= {"center_std_mm": u.center_std_mm, "rotation_std_deg": u.rotation_std_deg}
            if u.geometry is not None:
                out |= {"geometry_std": u.geometry.std, "geometry_std_mm": u.geometry.std_mm,
                        "geometry_rotation_std_deg": u.geometry.rotation_std_deg}
        if self.intrinsics is not None:
            out["intrinsics"] = self.intrinsics.to_json()
        if self.warnings is not None:
            out["warnings"] = list(self.warnings)
        if self.judged is not None:
            out |= {key: getattr(self.judged, key) for key in JudgedFigures.KEYS}
            out["uncovered"] = list(self.judged.uncovered) if self.judged.uncovered is not None else None
        if self.verdict is not None:
            out["verdict"] = dict(self.verdict)
        if self.focal_limit is not None:
            out |= self.focal_limit.to_json()
        if self.moved is not None:
            out["moved"] = self.moved.to_json()
        return out

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> CameraFigures:
        """A camera's entry of a result; the keys of a group it lacks leave the group None."""
        def has(*keys: str) -> bool:
            return any(k in doc for k in keys)

        points = PointFigures(doc.get("point_observations"), doc.get("point_rms_px")) if has(
            "point_observations", "point_rms_px") else None
        geometry = GeometryUncertainty(doc.get("geometry_std"), doc.get("geometry_std_mm"),
                                       doc.get("geometry_rotation_std_deg")) if has(
            "geometry_std", "geometry_std_mm", "geometry_rotation_std_deg") else None
        uncertainty = PoseUncertainty(doc.get("center_std_mm"), doc.get("rotation_std_deg"), geometry) if has(
            "center_std_mm", "rotation_std_deg") or geometry is not None else None
        intrinsics = doc.get("intrinsics")
        uncovered = doc.get("uncovered")
        judged = JudgedFigures(**{k: doc.get(k) for k in JudgedFigures.KEYS} | {
            "uncovered": tuple(uncovered) if isinstance(uncovered, list) else None}) if has(*JudgedFigures.KEYS) else None
        warnings = doc.get("warnings")
        return cls(
            doc.get("reprojection_rms_px"), doc.get("observations"), doc.get("frames_with_both_ends"),
            tuple(WorstFrame(w.get("frame"), w.get("error_px")) for w in doc.get("worst_frames") or ()), doc.get("initial_pose"),
            points, uncertainty, RefinedIntrinsics.from_json(intrinsics) if isinstance(intrinsics, Mapping) else None,
            tuple(warnings) if isinstance(warnings, list) else None, judged, doc.get("verdict"),
            FocalLimitFigures.from_json(doc) if isinstance(doc.get("focal_limit"), Mapping) else None,
            Movement.from_json(doc["moved"]) if isinstance(doc.get("moved"), Mapping) else None,
        )


@dataclass(frozen=True)
class WandReport:
    """The wand's figures: its given length, the mean and spread of its free (unconstrained)
    lengths at the final poses, metres, over ``frames_used`` frames; ``marker_pairs``, a wand of
    three or more markers' each pair of markers (:func:`wandcal.calib.solve.markerwand.marker_pair_lengths`)."""

    length_m: float | None
    length_mean_m: float | None
    length_std_m: float | None
    frames_used: int | None
    marker_pairs: tuple[Mapping[str, Any], ...] | None = None

    def to_json(self) -> Json:
        out: Json = {"length_m": self.length_m, "length_mean_m": self.length_mean_m, "length_std_m": self.length_std_m,
                     "frames_used": self.frames_used}
        return out | ({"marker_pairs": [dict(p) for p in self.marker_pairs]} if self.marker_pairs is not None else {})

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> WandReport:
        pairs = doc.get("marker_pairs")
        return cls(doc.get("length_m"), doc.get("length_mean_m"), doc.get("length_std_m"), doc.get("frames_used"),
                   tuple(pairs) if isinstance(pairs, list) else None)


@dataclass(frozen=True)
class SolverReport:
    """What the refinement reports: ``method`` ("ba", "lp", "paper"), ``info`` its own figures in
    the order it gave them (``status``, ``iterations``, ``seconds`` and each method's others:
    calib/solve/), ``solved_only`` the cameras a re-solve placed (None for a whole calibration)
    and ``total_seconds`` the whole calibration's wall time."""

    method: str | None
    info: Mapping[str, Any]
    solved_only: tuple[str, ...] | None = None
    total_seconds: float | None = None

    @property
    def status(self) -> str | None:
        return self.info.get("status")

    @property
    def iterations(self) -> int | None:
        return self.info.get("iterations")

    @property
    def refined_intrinsics(self) -> tuple[str, ...]:
        return tuple(self.info.get("refined_intrinsics") or ())

    def to_json(self) -> Json:
        out: Json = {"method": self.method} | dict(self.info)
        if self.solved_only is not None:
            out["solved_only"] = list(self.solved_only)
        return out | ({"total_seconds": self.total_seconds} if self.total_seconds is not None else {})

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> SolverReport:
        info = {k: v for k, v in doc.items() if k not in ("method", "solved_only", "total_seconds")}
        solved = doc.get("solved_only")
        return cls(doc.get("method"), info, tuple(solved) if isinstance(solved, list) else None, doc.get("total_seconds"))


@dataclass(frozen=True)
class StaticFitNoise:
    """A static object's blobs' own noise (:func:`wandcal.calib.start.world.static_fit_expectation`):
    their reprojection RMS, pixels, and the static fit's RMS that noise alone would give, metres."""

    static_blob_rms_px: float | None
    expected_fit_rms_m: float | None


@dataclass(frozen=True)
class Placement:
    """How well the world frame itself is placed: its origin's standard error, mm (None without
    a scale), and its axes', degrees."""

    origin_std_mm: float | None
    axes_std_deg: float | None


@dataclass(frozen=True)
class WorldFrame:
    """The world frame a result is expressed in.

    frame: "static_object", "axis" or "wand_volume"; description: in words; details: what set it,
    in the order :func:`wandcal.calib.start.world.world_frame` gave them (``fit_rms_m``,
    ``cameras_used``, ``origin``, ``x_camera``, ``axes_given``, ...); scale: "wand" (metres) or
    "arbitrary"; static_fit: the static blobs' noise (with a covariance); placement: the frame's
    own uncertainty (with a covariance).
    """

    frame: str | None
    description: str | None
    details: Mapping[str, Any] = field(default_factory=dict)
    scale: str | None = None
    static_fit: StaticFitNoise | None = None
    placement: Placement | None = None

    OWN = ("frame", "description", "scale", "static_blob_rms_px", "expected_fit_rms_m", "placement")

    def to_json(self) -> Json:
        out: Json = {"frame": self.frame, "description": self.description} | dict(self.details)
        if self.scale is not None:
            out["scale"] = self.scale
        if self.static_fit is not None:
            out |= {"static_blob_rms_px": self.static_fit.static_blob_rms_px,
                    "expected_fit_rms_m": self.static_fit.expected_fit_rms_m}
        if self.placement is not None:
            out["placement"] = {"origin_std_mm": self.placement.origin_std_mm, "axes_std_deg": self.placement.axes_std_deg}
        return out

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> WorldFrame:
        placement = doc.get("placement")
        static = StaticFitNoise(doc.get("static_blob_rms_px"), doc.get("expected_fit_rms_m")) if (
            "static_blob_rms_px" in doc or "expected_fit_rms_m" in doc) else None
        return cls(doc.get("frame"), doc.get("description"), {k: v for k, v in doc.items() if k not in cls.OWN},
                   doc.get("scale"), static,
                   Placement(placement.get("origin_std_mm"), placement.get("axes_std_deg"))
                   if isinstance(placement, Mapping) else None)


@dataclass(eq=False)
class CalibrationResult:
    """Poses in the world frame and everything the report needs.

    R: (N, 3, 3), t: (N, 3) world->camera, metres; wand: (F, 2, 3) wand ends, metres, and frames:
    (F,) their capture frame numbers (both empty in a result read from a file, which does not
    hold them); cameras: (N,) figures in rig order; dropped: camera-frames left out, by reason;
    points: (T, 3) the single-point tracks' refined points, world frame; verdict: the rig's
    {"level", "reasons", "faults", "placement", ...} (calib/judge/verdict.py); sync: the cameras'
    time offsets under ``sync="auto"`` (docs/sync.md).
    """

    rig: Rig
    R: np.ndarray
    t: np.ndarray
    wand: np.ndarray
    frames: np.ndarray
    cameras: tuple[CameraFigures, ...]
    wand_report: WandReport | None
    solver: SolverReport
    world: WorldFrame
    dropped: Mapping[str, int]
    warnings: list[str] = field(default_factory=list)
    points: np.ndarray | None = None
    verdict: Mapping[str, Any] | None = None
    sync: Mapping[str, Any] | None = None

    @property
    def centers(self) -> np.ndarray:
        """(N, 3) camera centres, world frame, metres."""
        return camera_centers(self.R, self.t)

    def to_json(self) -> Json:
        """The ``wandcal-result/1`` document (docs/result-format.md)."""
        cams = []
        centers = self.centers
        for i, cam in enumerate(self.rig.cameras):
            entry: Json = {
                "id": cam.id,
                "R": self.R[i].tolist(),
                "t": self.t[i].tolist(),
                "center": centers[i].tolist(),
                "K": cam.K.tolist(),
                "dist": cam.dist.tolist(),
                "width": cam.width,
                "height": cam.height,
            }
            if cam.model != "pinhole":
                entry["model"] = cam.model
            cams.append(entry | self.cameras[i].to_json())
        return {
            "format": RESULT_FORMAT,
            "cameras": cams,
            "wand": self.wand_report.to_json() if self.wand_report is not None else None,
            "solver": self.solver.to_json(),
            "world": self.world.to_json(),
            "dropped": dict(self.dropped),
            "verdict": self.verdict,
            "warnings": list(self.warnings),
        } | ({"sync": self.sync} if self.sync is not None else {})


def camera_observations(camera: Mapping[str, Any]) -> int:
    """A camera's observations in a result document's camera entry: its wand ends and its single
    points together (``observations`` + ``point_observations``). The one count the verdict, the
    command line's table and the report give as a camera's observations."""
    return int(camera.get("observations") or 0) + int(camera.get("point_observations") or 0)


def result_from_json(doc: Mapping[str, Any], rig: Rig, R: np.ndarray, t: np.ndarray) -> CalibrationResult:
    """The typed result of a ``wandcal-result/1`` document whose cameras, poses and fields have been
    checked (:func:`wandcal.capture.result_file.check_result`).

    Args:
        doc: the document; rig: its cameras (intrinsics as refined) and wand length;
        R, t: (N, 3, 3), (N, 3) its world->camera poses, metres.
    """
    wand, solver, world = doc.get("wand"), doc.get("solver"), doc.get("world")
    return CalibrationResult(
        rig=rig, R=np.asarray(R, float), t=np.asarray(t, float), wand=np.zeros((0, 2, 3)), frames=np.zeros(0, int),
        cameras=tuple(CameraFigures.from_json(entry) for entry in doc["cameras"]),
        wand_report=WandReport.from_json(wand) if isinstance(wand, Mapping) else None,
        solver=SolverReport.from_json(solver if isinstance(solver, Mapping) else {}),
        world=WorldFrame.from_json(world if isinstance(world, Mapping) else {}),
        dropped=dict(doc.get("dropped") or {}), warnings=list(doc.get("warnings") or []), verdict=doc.get("verdict"),
        sync=doc.get("sync"),
    )
