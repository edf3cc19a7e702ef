"""The input kinds of the every-input-through-every-command matrix (issue 32), built once for
``tests/calib/test_input_matrix.py`` and ``bench/bench_matrix.py``: simulated rigs of every shape
and the real sessions of ../shared/data, read at run time (never copied; absent ones are None).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from bench.real_sessions import BROWN, BROWN_MAT, SHARED_DATA, SVOBODA, USHICHKA, USHICHKA_HEIGHT
from wandcal.calib.rig import PointObservations, Rig

CW500_M = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.5, 0.0, 0.0]])  # a 3-marker collinear wand, metres
TEE_M = np.array([[0.0, 0.0, 0.0], [0.18, 0.0, 0.0], [0.42, 0.0, 0.0], [0.18, 0.12, 0.0], [0.18, 0.30, 0.0]])  # planar
# the simulated kinds: small rigs (4 cameras, 300 frames) keep the matrix fast
SIMULATED = ("lframe", "wand_only", "three_marker", "planar_wand", "wand_points", "points_only")
# the real sessions of ../shared/data that are captures (observations to calibrate from)
REAL = ("sparse_digitised", "ushichka", "easywand_cpp", "mcsc_points")
CPP = "easywand_cpp_sample_3cam"


@dataclasses.dataclass(frozen=True, eq=False)
class Kind:
    """One input kind: a rig and what it observed (any of them None where the kind has none)."""

    name: str
    rig: Rig
    wand: object
    static: object = None
    points: PointObservations | None = None
    axis: object = None
    source: str = "simulated"


def build(name: str) -> Kind | None:
    """The input kind ``name`` (one of ``SIMULATED`` or ``REAL``); None when its data are absent."""
    if name in REAL:
        return _real(name)
    from wandcal.calib.sim.scenes import pairwise_points
    from wandcal.calib.sim.simulate import simulate_capture

    markers = {"three_marker": CW500_M, "planar_wand": TEE_M}.get(name)
    sim = simulate_capture(4, 300, 0.3, 0.0, name == "lframe", 1, wand_markers=markers)
    if name in ("lframe", "wand_only", "three_marker", "planar_wand"):
        return Kind(name, sim.rig, sim.wand, sim.static)
    points = pairwise_points(sim, 400, np.random.default_rng(5), third=0.8)
    if name == "wand_points":
        return Kind(name, sim.rig, sim.wand, None, points)
    if name == "points_only":
        return Kind(name, dataclasses.replace(sim.rig, wand_length=None), None, None, points)
    raise ValueError(f"unknown input kind {name!r}; choose one of {', '.join(SIMULATED + REAL)}")


def _real(name: str) -> Kind | None:
    """A real session's capture, or None where ../shared/data does not hold it."""
    from wandcal.capture.importers.easywand import read_easywand_files, read_easywand_mat

    if name == "sparse_digitised":  # Brown 1: 2-8 wand frames a camera, 220-370 background tracks, axis points
        path = SHARED_DATA / BROWN / "calibration1" / BROWN_MAT
        cap = read_easywand_mat(path).capture if path.is_file() else None
    elif name == "ushichka":
        path = SHARED_DATA / USHICHKA / "round3_2018-07-28_easyWandData.mat"
        cap = read_easywand_mat(path, height=USHICHKA_HEIGHT).capture if path.is_file() else None
    elif name == "easywand_cpp":  # its wand has no length (the import refuses the wand then): its background points
        path = SHARED_DATA / CPP / "bkgdPts.csv"
        cap = read_easywand_files(None, path.parent / "RGBsetup_profile.txt", None, background=path).capture \
            if path.is_file() else None
    else:  # MultiCamSelfCal's point tracks: no wand, no scale
        from wandcal.capture.importers.svoboda import read_svoboda

        path = SHARED_DATA / SVOBODA
        cap = read_svoboda(path).capture if path.is_dir() else None
    if cap is None:
        return None
    wand = cap.wand if cap.wand is not None and len(cap.wand) else None
    return Kind(name, cap.rig, wand, cap.static, cap.points, cap.axis, source=str(Path(path).relative_to(SHARED_DATA)))
