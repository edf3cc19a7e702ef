"""A camera's figures in a calibration's result, as typed values: where it stands and how sure
(:class:`GeometryUncertainty`, :class:`PoseUncertainty`), its residuals (:class:`PointFigures`,
:class:`WorstFrame`), the intrinsics refined (:class:`RefinedIntrinsics`), the judgement's reading
(:class:`JudgedFigures`, :class:`FocalLimitFigures`, :class:`Movement`), all held by
:class:`CameraFigures`. The document they write and read is :mod:`wandcal.calib.run.result`'s.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

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
    """How far a camera's position hinges on intrinsics that were given, not refined
    (:mod:`wandcal.calib.judge.intrinsic_limits`): ``focal_limit`` the focal length's figures (mm
    per 1%, the sigma assumed and its source, the data's own; None where it was refined),
    ``honest_std_mm`` the geometry sigma with every given intrinsic's part (``honest_std`` in the
    result's units without a scale), ``lens_limits`` each other given parameter's figures (cx, cy,
    k1, k2, p1, p2: its sigma, mm for it, the data's own standard error in sigmas; None in a result
    written before them)."""

    focal_limit: Mapping[str, Any] | None
    honest_std_mm: float | None = None
    honest_std: float | None = None
    lens_limits: Mapping[str, Any] | None = None

    def to_json(self) -> Json:
        out: Json = {}
        if self.focal_limit is not None:
            out["focal_limit"] = dict(self.focal_limit)
        if self.lens_limits is not None:
            out["lens_limits"] = {k: dict(v) for k, v in self.lens_limits.items()}
        if self.honest_std_mm is not None:
            out["geometry_std_honest_mm"] = self.honest_std_mm
        if self.honest_std is not None:
            out["geometry_std_honest"] = self.honest_std
        return out

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> FocalLimitFigures:
        focal, lens = doc.get("focal_limit"), doc.get("lens_limits")
        return cls(focal if isinstance(focal, Mapping) else None, doc.get("geometry_std_honest_mm"),
                   doc.get("geometry_std_honest"), lens if isinstance(lens, Mapping) else None)


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
            FocalLimitFigures.from_json(doc) if any(isinstance(doc.get(k), Mapping) for k in ("focal_limit", "lens_limits"))
            else None,
            Movement.from_json(doc["moved"]) if isinstance(doc.get("moved"), Mapping) else None,
        )
