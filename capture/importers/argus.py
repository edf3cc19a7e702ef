"""Argus Wand's inputs as a capture: paired (wand) points, optional unpaired and reference points,
all ``*-xypts.csv`` tables saved by Argus Clicker, and a camera profile.

Argus writes DLTdv's layout (:mod:`wandcal.capture.importers.dltdv`): one row per frame (dense .csv; the
first row of the file after the header is frame 0), columns ``{track}_cam_{n}_x``,
``{track}_cam_{n}_y`` for each track, then camera; y-up pixels with the origin at the lower left;
NaN where not digitised. The paired file holds two tracks, the wand's two ends. The profile has
one row per camera: ``camera#, f, width, height, cx, cy, AR, k1, k2, t1, t2, k3``. Reference
points (Argus docs): 1 point sets the origin, 2 the origin and +z, 3 the origin, +x and +y, 4
the origin, +x, +y and +z; given down the rows of one track, or as one track per point in a
common frame. More rows are a gravity or plane reference, not imported.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wandcal.calib.rig import AxisObservations, Rig
from wandcal.capture.folder import Capture, CaptureFormatError
from wandcal.capture.importers.dltdv import (
    AXIS_ROLES_BY_COUNT,
    XyTable,
    axis_from_points,
    check_inside,
    first_free_frame,
    parse_profile,
    parse_xypts,
    points_from_table,
    read_text,
    wand_from_table,
)
from wandcal.capture.importers.summary import Imported


def read_argus(paired: str | Path, profile: str | Path, wand_length_m: float, unpaired: str | Path | None = None,
               reference: str | Path | None = None, height: int | None = None) -> Imported:
    """Import an Argus Wand session.

    Args:
        paired: the wand's ``*-xypts.csv`` (two tracks).
        profile: the camera profile (one row per camera, in the tables' camera order).
        wand_length_m: the wand's marker distance, metres.
        unpaired: optional ``*-xypts.csv`` of unpaired points (any number of tracks): points.csv.
        reference: optional ``*-xypts.csv`` of reference points: axis.csv.
        height: image height in pixels for every camera, overriding the profile's.
    """
    cameras = parse_profile(read_text(profile, "Argus camera profile"), str(profile), height)
    n = len(cameras)
    wand_table = parse_xypts(read_text(paired, "paired (wand) points -xypts.csv"), str(paired), n, 4 * n)
    check_inside(wand_table.values, cameras, str(paired))
    wand, one_end = wand_from_table(wand_table, cameras)
    notes = []
    if one_end.any():
        notes.append("left out camera-frames of the wand with one end only: "
                     + ", ".join(f"{c.id} {k}" for c, k in zip(cameras, one_end)))
    points = None
    if unpaired is not None:
        table = parse_xypts(read_text(unpaired, "unpaired points -xypts.csv"), str(unpaired), n)
        check_inside(table.values, cameras, str(unpaired))
        first = first_free_frame(int(wand_table.frames.max()))
        points = points_from_table(table, cameras, first)
        tracks = table.values.shape[1] // (2 * n)
        span = int(table.frames.max()) + 1
        notes.append(f"unpaired points: row r of track t (0-based) in {unpaired} is points.csv frame "
                     f"{first} + {span}·t + r" if tracks > 1 else
                     f"unpaired points: row r of {unpaired} is points.csv frame {first} + r")
        points = points if len(points) else None
    axis = None
    if reference is not None:
        table = parse_xypts(read_text(reference, "reference points -xypts.csv"), str(reference), n)
        check_inside(table.values, cameras, str(reference))
        axis, note = _reference(table, cameras)
        notes.append(note)
    try:
        rig = Rig(tuple(cameras), float(wand_length_m))
    except (ValueError, TypeError) as exc:
        raise CaptureFormatError(f"--wand-length: {exc}") from None
    notes.append("frames are the rows of the paired file (0-based; Argus Clicker shows them 1-based)")
    source = ", ".join(str(p) for p in (paired, profile, unpaired, reference) if p is not None)
    return Imported(Capture(rig=rig, wand=wand, static=None, points=points, axis=axis), source, tuple(notes))


def _reference(table: XyTable, cameras) -> tuple[AxisObservations | None, str]:
    """Reference points down the rows of one track, or one point per track in a common row."""
    n = len(cameras)
    tracks = table.values.shape[1] // (2 * n)
    xy = table.values.reshape(len(table.values), tracks, n, 2)
    if tracks == 1:
        rows = xy[np.any(np.isfinite(xy), axis=(1, 2, 3)), 0]
        layout = "down the rows of one track"
    else:
        with_data = np.any(np.isfinite(xy), axis=(2, 3))  # row, track
        if np.any(with_data.sum(axis=0) != 1):
            return None, (f"{table.source}: {tracks} reference tracks, but not each with exactly one digitised "
                          "frame; not imported (digitise each reference point in one common frame)")
        rows = np.stack([xy[np.flatnonzero(with_data[:, t])[0], t] for t in range(tracks)])
        layout = "one per track"
    if len(rows) not in AXIS_ROLES_BY_COUNT:
        return None, (f"{table.source}: {len(rows)} reference points are a gravity or plane reference, not 1-4 axis "
                      "points; not imported (wandcal aligns no axes to gravity or planes)")
    roles = AXIS_ROLES_BY_COUNT[len(rows)]
    return axis_from_points(rows, roles, cameras), (
        f"{table.source}: {len(rows)} reference points ({layout}) taken as {', '.join(roles)}")
