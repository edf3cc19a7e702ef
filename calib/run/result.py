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
from wandcal.calib.run.camera_figures import CameraFigures

RESULT_FORMAT = "wandcal-result/1"
Json = dict[str, Any]


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
