"""A start that fails because one camera is out of time, named with its shift.

On a hand-digitised session a camera a frame or two out of time sees the wand where the others
saw it a frame or two before or after: no relative pose fits its wand ends, and the start
(:func:`wandcal.calib.start.initial.initial_poses`) refuses it as a camera that "cannot be
placed". What helps the user then is the camera and its shift, not the wand's length. When the
start has refused, :func:`out_of_time_refusal` looks for a shift that makes the data agree:

- **whole frames**: each camera's whole-frame offset by ``--sync auto``'s own search
  (:func:`wandcal.calib.start.offsets.whole_frames.frame_offsets`, +-:data:`MAX_SHIFT` frames). The
  cameras whose offset differs from the majority's are out of time by that difference;
- **a fraction of a frame** (no whole shift found): each camera's wand samples resampled, linear
  between its consecutive frames, at :data:`FRACTIONS` of a frame either way (a few starts of a
  small rig, :data:`MAX_FRACTION_CAMERAS` cameras at most).

A shift is only named when the start, refused without it, places every camera with it, and (for a
fraction) no other camera's shift does too. Offsets take docs/result-format.md's sign: positive is
late, the camera's frame k exposed at the others' frame k + offset.
"""

from __future__ import annotations

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.observations import PointTracks, WandPairs
from wandcal.calib.rig import Rig
from wandcal.calib.solve.sync.fit import why_untimeable
from wandcal.calib.solve.sync.report import sync_advice
from wandcal.calib.start.initial import UnplacedCamera, initial_poses

MAX_SHIFT = 8  # whole frames searched either way (--sync auto's default search)
# fractions of a frame tried either way: a camera off by 0.3 frame agrees at 0.25, one off by 0.5
# at 0.5; the start tolerates the quarter frame left over (its RANSAC threshold is 2 px)
FRACTIONS = (0.25, 0.5)
# a clock's drift through the capture tried either way (offset at the camera's last frame): a
# clock one frame slow by the end agrees at 1, half a frame at 0.5
DRIFTS = (1.0, 0.5)
MAX_FRACTION_CAMERAS = 5  # a start per camera and fraction: 4 per camera, ~0.3 s each on a digitised session


def resampled(pairs: WandPairs, c: int, shift: float, drift: float = 0.0) -> WandPairs:
    """The pairs with camera c's samples at frame k taken from its own time k + ``shift`` (frames;
    linear between its samples at the two frames around it, each end paired with the nearer one);
    its frames without both neighbours are left out. As if c were ``-shift`` frames late.
    ``drift``: frames added to the shift in proportion through c's frames, from 0 at its first to
    ``drift`` at its last (a clock running fast or slow)."""
    mine = np.flatnonzero(pairs.camera == c)
    number = pairs.frames[pairs.frame]
    row_of = {int(f): int(i) for f, i in zip(number[mine], mine)}
    first, last = (int(number[mine].min()), int(number[mine].max())) if len(mine) else (0, 1)
    kept, xy, uv = [], [], []
    for i in mine:
        here = shift + drift * (int(number[i]) - first) / max(last - first, 1)
        lo = int(np.floor(here))
        w = here - lo
        a, b = row_of.get(int(number[i]) + lo), row_of.get(int(number[i]) + lo + 1)
        if a is None or (w > 0 and b is None):
            continue
        xa, ua = pairs.xy[a], pairs.uv[a]
        if w > 0:
            xb, ub = pairs.xy[b], pairs.uv[b]
            if np.linalg.norm(xa - xb) > np.linalg.norm(xa - xb[::-1]):  # the ends in the same order
                xb, ub = xb[::-1], ub[::-1]
            xa, ua = (1 - w) * xa + w * xb, (1 - w) * ua + w * ub
        kept.append(int(number[i]))
        xy.append(xa)
        uv.append(ua)
    other = pairs.camera != c
    num = np.concatenate([number[other], np.array(kept, np.int64)])
    cam = np.concatenate([pairs.camera[other], np.full(len(kept), c)])
    all_xy = np.concatenate([pairs.xy[other], np.reshape(xy, (-1, 2, 2))])
    all_uv = np.concatenate([pairs.uv[other], np.reshape(uv, (-1, 2, 2))])
    order = np.lexsort((cam, num))
    frames, frame = np.unique(num[order], return_inverse=True)
    return WandPairs(frame, cam[order], all_xy[order], all_uv[order], frames, pairs.dropped)


def _places(rig: Rig, pairs: WandPairs, static_poses: list | None, tracks: PointTracks | None) -> bool:
    try:
        initial_poses(rig, pairs, static_poses, points=tracks)
    except CalibrationError:
        return False
    return True


def whole_frame_shifts(rig: Rig, pairs: WandPairs, static_poses: list | None,
                       tracks: PointTracks | None) -> dict[int, int]:
    """{camera: offset in whole frames (positive: late)} of the cameras out of time against the
    majority, when shifting them lets the start place every camera; empty otherwise."""
    from wandcal.calib.start.offsets.whole_frames import frame_offsets, shift_pairs

    try:
        found = frame_offsets(rig, pairs, MAX_SHIFT)
    except CalibrationError:
        return {}
    values, counts = np.unique(found.offsets, return_counts=True)
    majority = int(values[np.argmax(counts)])
    relative = found.offsets - majority
    odd = np.flatnonzero(relative)
    if not len(odd) or len(odd) >= len(rig.cameras) / 2:
        return {}
    if not _places(rig, shift_pairs(pairs, found.offsets), static_poses, tracks):
        return {}
    return {int(c): int(relative[c]) for c in odd}


def fractional_shift(rig: Rig, pairs: WandPairs, static_poses: list | None, tracks: PointTracks | None,
                     suspect: int | None = None) -> tuple[int, float] | None:
    """(camera, offset in frames, positive: late) of the one camera whose samples, resampled by a
    fraction of a frame (:data:`FRACTIONS`), let the start place every camera; None where none
    does, or more than one camera does. ``suspect``: the camera the start could not place, the
    only one tried (the cameras that agree were placed before it)."""
    if len(rig.cameras) > MAX_FRACTION_CAMERAS:
        return None
    found = []
    for c in range(len(rig.cameras)) if suspect is None else (suspect,):
        for shift in (s * sign for s in FRACTIONS for sign in (1, -1)):
            if _places(rig, resampled(pairs, c, shift), static_poses, tracks):
                found.append((c, -shift))  # taken from its time k + shift: it was -shift late
                break
    return found[0] if len(found) == 1 else None


def drifting_clock(rig: Rig, pairs: WandPairs, static_poses: list | None, tracks: PointTracks | None,
                   suspect: int | None) -> tuple[int, float] | None:
    """(camera, its offset at its last frame, positive: late) of the camera the start could not
    place (``suspect``) whose clock runs slow or fast: its samples resampled with an offset growing
    from 0 at its first frame to :data:`DRIFTS` frames at its last let the start place every
    camera; None where no drift does, or both signs do."""
    if suspect is None or len(rig.cameras) > MAX_FRACTION_CAMERAS:
        return None
    found = [(suspect, -drift) for drift in (d * sign for d in DRIFTS for sign in (1, -1))
             if _places(rig, resampled(pairs, suspect, 0.0, drift), static_poses, tracks)]
    return found[0] if found and all(np.sign(d) == np.sign(found[0][1]) for _, d in found) else None


_SEARCH_ERRORS = (np.linalg.LinAlgError, FloatingPointError, ValueError)  # numbers too extreme for a search


def _searched(search, *args):
    """``search(*args)``, or None where its numbers are too extreme (a damaged rig.json)."""
    try:
        return search(*args)
    except _SEARCH_ERRORS:
        return None


def _named_out_of_time(error: CalibrationError, rig: Rig, pairs: WandPairs, static_poses: list | None,
                       tracks: PointTracks | None) -> tuple[str, int | None] | None:
    """The camera out of time and by how much, as a sentence: by whole frames, else a constant fraction
    of a frame, else a drifting clock (the first search that places every camera), and the camera
    whose fraction of a frame ``--sync auto`` would have to fit (None for whole frames); None if
    no search places every camera."""
    ids = rig.ids
    suspect = error.camera if isinstance(error, UnplacedCamera) else None
    whole = _searched(whole_frame_shifts, rig, pairs, static_poses, tracks)
    if whole is None:
        return None  # the whole-frame search failed on the numbers: the start's own refusal stands
    if whole:
        return "; ".join(f"{ids[c]} is out of time: its wand agrees with the other cameras' only with its frames "
                         f"shifted, {abs(d)} frame{'s' if abs(d) != 1 else ''} {'late' if d > 0 else 'early'} "
                         f"(offset {d:+d}: positive is late)" for c, d in whole.items()), None
    fraction = _searched(fractional_shift, rig, pairs, static_poses, tracks, suspect)
    if fraction is not None:
        c, d = fraction
        return (f"{ids[c]} is out of time: its wand agrees with the other cameras' only with its samples moved "
                f"in time, about {abs(d):g} frame {'late' if d > 0 else 'early'} (offset {d:+g}: positive is late)"), c
    drift = _searched(drifting_clock, rig, pairs, static_poses, tracks, suspect)
    if drift is None:
        return None
    c, d = drift
    return (f"{ids[c]} is out of time: its wand agrees with the other cameras' only with its samples moved in "
            f"time by an offset growing from 0 at its first frame to about {abs(d):g} frame "
            f"{'late' if d > 0 else 'early'} at its last (a clock running {'slow' if d > 0 else 'fast'}, or a "
            f"constant offset of a fraction of a frame, which the start cannot tell apart; offset {d:+g} at its "
            "last frame: positive is late)"), c


def out_of_time_refusal(error: CalibrationError, rig: Rig, pairs: WandPairs, static_poses: list | None,
                        tracks: PointTracks | None) -> CalibrationError:
    """The start's refusal ``error`` with the camera out of time named first, where a shift of its
    frames lets every camera be placed (module docstring); ``error`` itself where none does."""
    if len(rig.cameras) < 3 or not len(pairs):
        return error  # two cameras cannot say which of them is out of time
    found = _named_out_of_time(error, rig, pairs, static_poses, tracks)
    if found is None:
        return error
    named, fraction = found
    fix = ("calibrate with --sync auto, which finds and corrects each camera's offset, or check its trigger cable "
           "and settings")
    why = "" if fraction is None else why_untimeable(pairs, rig, fraction)
    if why:  # --sync auto would hold it at whole frames (its own test): not the fix
        fix = f"check its trigger cable and settings{sync_advice(why)}"
    return CalibrationError(f"{named}; {fix}. Without the shift the start failed: {error}")
