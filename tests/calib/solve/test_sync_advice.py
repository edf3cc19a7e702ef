"""Whether ``--sync auto`` can time a camera from its wand (calib/solve/sync/tracks.py's
``TrackSmoothness``, the test ``fit_timing`` holds a camera by), and the advice that follows (issue
31, "advice that fits"): where no camera's wand track can be interpolated, ``--sync auto``'s warning
says so with each camera's figure beside its limit, and a timing fault does not send the user to
``--sync auto`` for a fraction of a frame it cannot fit."""

from __future__ import annotations

import numpy as np
import pytest

from wandcal.calib.geometry import project_normalized
from wandcal.calib.judge.faults.timing_pairs import CameraTiming, camera_timings, timing_fault
from wandcal.calib.observations import WandPairs
from wandcal.calib.sim.simulate import look_at
from wandcal.calib.solve.sync import fit_timing, sync_report
from wandcal.calib.solve.sync.fit import smoothness
from wandcal.calib.solve.sync.report import NO_SYNC_ADVICE
from wandcal.calib.solve.sync.tracks import ROUGH_PX

FOCAL_PX = 1000.0
NOISE_PX = 0.3
FRAMES = 200
# the interpolation error of noise alone: the cubic's weights (-1, 4, 4, -1) / 6 add 34/36 of a
# blob's variance to its own, so each axis errs by sqrt(1 + 34/36) sigma; the larger of two ends'
# 2D errors has its median at 1.567 times that (a Rayleigh pair: (1 - exp(-r^2 / 2))^2 = 1/2)
NOISE_ROUGH_PX = 1.567 * np.sqrt(1 + 34 / 36) * NOISE_PX
SMOOTH_PERIOD = 200.0  # frames a loop: ~4 px a frame, the path's own share of the error < 0.01 px
# 8 frames a loop (a wand waved too fast for its frame rate): the cubic through frames -2, -1, 1, 2
# misses the path's cos(w t) term by 1 - (8 cos w - 2 cos 2w) / 6 = 5.7% of its 0.4 m (2.3 cm) and
# its sin(2 w t) term by 2/3 of its 0.3 m; each camera sees one of them across its view, at least
# 2.3 cm at 3 m, ~7.6 px: above ROUGH_PX on every camera
FAST_PERIOD = 8.0


def _capture(period: float, late: float = 0.0, seed: int = 0):
    """Three cameras 3 m out and a 0.5 m wand whose centre loops through a 1 m volume once every
    ``period`` frames, turning as it goes; camera 2 ``late`` frames late. (R, t, pairs with the
    ends labelled alike in every camera, focal (3, 2) pixels.)"""
    centres = [[3, 0, 1], [0, 3, 1.2], [-3, 0, 0.8]]
    poses = [look_at(np.array(c, float), np.zeros(3)) for c in centres]
    R, t = np.array([p[0] for p in poses]), np.array([p[1] for p in poses])
    rng = np.random.default_rng(seed)
    frame, camera, xy = [], [], []
    for c in range(3):
        time = np.arange(FRAMES) + (late if c == 2 else 0.0)
        w = 2 * np.pi * time / period
        centre = np.stack([0.4 * np.cos(w), 0.3 * np.sin(2 * w), 0.2 * np.sin(w)], axis=1)
        along = np.stack([np.cos(w / 3), np.sin(w / 3), np.full_like(w, 0.3)], axis=1)
        along /= np.linalg.norm(along, axis=1, keepdims=True)
        ends = [project_normalized(R[c], t[c], centre + s * 0.25 * along) for s in (-1, 1)]
        x = np.stack(ends, axis=1) + rng.normal(0, NOISE_PX / FOCAL_PX, (FRAMES, 2, 2))
        frame.append(np.arange(FRAMES))
        camera.append(np.full(FRAMES, c))
        xy.append(x)
    f, cam, x = (np.concatenate(v) for v in (frame, camera, xy))
    order = np.lexsort((cam, f))
    pairs = WandPairs(f[order], cam[order], x[order], x[order] * FOCAL_PX, np.arange(FRAMES))
    return R, t, pairs, np.full((3, 2), FOCAL_PX)


def test_a_smooth_track_is_timed_and_a_fast_one_is_held_with_its_figure():
    _, _, smooth_pairs, focal = _capture(SMOOTH_PERIOD)
    smooth = smoothness(smooth_pairs, focal)
    assert smooth.interpolable.all() and all(smooth.why_not(c) == "" for c in range(3))
    # the noise alone, to within the spread of a median of 200 frames (a few per cent) and the path's share
    assert np.all(np.abs(smooth.rough_px - NOISE_ROUGH_PX) < 0.25 * NOISE_ROUGH_PX)
    _, _, fast_pairs, _ = _capture(FAST_PERIOD)
    fast = smoothness(fast_pairs, focal)
    assert not fast.interpolable.any() and np.all(fast.rough_px > ROUGH_PX)
    why = fast.why_not(1)
    assert f"{fast.rough_px[1]:.1f} px" in why and f"{ROUGH_PX:g} px" in why


def test_sync_auto_says_when_it_can_time_no_camera_and_what_to_do():
    R, t, pairs, focal = _capture(FAST_PERIOD, late=0.3)
    timing = fit_timing(R, t, pairs, focal, 0)
    assert timing.held.all()  # as before: held at the whole-frame offsets
    _, warnings = sync_report(["a", "b", "c"], np.zeros(3, np.int64), 0, timing, None, None, False)
    assert len(warnings) == 1  # one warning for the rig, not one a camera
    assert "could not time any camera" in warnings[0] and NO_SYNC_ADVICE in warnings[0]
    for c in (1, 2):  # every camera but the reference, with its figure
        assert f"{timing.smoothness.rough_px[c]:.1f} px" in warnings[0]
    R, t, pairs, focal = _capture(SMOOTH_PERIOD, late=0.3)
    timing = fit_timing(R, t, pairs, focal, 0)
    _, warnings = sync_report(["a", "b", "c"], np.zeros(3, np.int64), 0, timing, None, None, False)
    assert not any("could not time" in w for w in warnings)


def test_a_timing_fault_sends_to_sync_auto_only_where_it_can_fit_the_fraction():
    R, t, pairs, focal = _capture(FAST_PERIOD, late=0.3)
    found = camera_timings(R, t, pairs, None, focal[:, 0])
    assert found and all(o.untimeable == smoothness(pairs, focal).why_not(o.camera) for o in found)
    # with (fx, fy) apart, the verdict judges each camera with both, as --sync auto does
    fxy = focal * np.array([1.0, 1.3])
    apart = camera_timings(R, t, pairs, None, fxy)
    assert apart and all(o.untimeable == smoothness(pairs, fxy).why_not(o.camera) for o in apart)
    assert np.allclose([o.effect_px for o in apart], [1.15 * o.effect_px for o in found], rtol=1e-12)  # the mean focal
    rough = next(o for o in found if o.camera == 2)
    message = timing_fault(["a", "b", "c"], CameraTiming(2, 0, 0.3, 0.01, 0.9, 40.0, 100, rough.untimeable))["message"]
    assert "whole frames only" in message and NO_SYNC_ADVICE in message and "calibrate with its offset" not in message
    # a whole-frame shift alone needs no track: the whole-frame search times it
    message = timing_fault(["a", "b", "c"], CameraTiming(2, 2, 2.0, 0.01, 0.9, 40.0, 100, rough.untimeable))["message"]
    assert "calibrate with its offset (--sync auto)" in message
    message = timing_fault(["a", "b", "c"], CameraTiming(2, 0, 0.3, 0.01, 0.9, 40.0, 100, ""))["message"]
    assert "calibrate with its offset (--sync auto)" in message


def test_the_easywand_cpp_sample_is_told_it_cannot_be_synchronised_from_the_wand(shared_data):
    """The easyWand C++ sample (~1 s): every camera's wand moves 41-56 px between its frames, so
    ``--sync auto`` holds them all, and its clean run's timing fault (cam2, 0.02 frame early) is
    not sent to it."""
    from wandcal.calib.run.calibrate import calibrate
    from wandcal.calib.run.options import CalibrationOptions
    from wandcal.capture.importers.easywand import read_easywand_files

    folder = shared_data / "easywand_cpp_sample_3cam"
    if not folder.is_dir():
        pytest.skip("the easyWand C++ sample is absent")
    cap = read_easywand_files(folder / "wandpts.csv", folder / "RGBsetup_profile.txt", 1.0,
                              folder / "bkgdPts.csv").capture
    result = calibrate(cap.rig, cap.wand, None, points=cap.points, axis=cap.axis,
                       options=CalibrationOptions(sync="auto"))
    said = [w for w in result.warnings if "could not time any camera" in w]
    assert len(said) == 1 and "limit is 5 px" in said[0] and NO_SYNC_ADVICE in said[0]
    timing = [f["message"] for f in result.verdict.get("faults", []) if f.get("kind") == "timing"]
    timing += [r for r in result.verdict.get("reasons", []) if "out of time" in r]
    assert all("calibrate with its offset" not in m for m in timing)


def test_the_start_refusing_a_fraction_of_a_frame_on_the_cpp_sample_does_not_send_to_sync_auto(shared_data):
    """cam1 half a frame early on the C++ sample (~0.5 s): the start refuses it, naming the offset;
    ``--sync auto`` refuses it too (it holds every camera at whole frames), so the refusal says what
    else to do."""
    from bench import real_faults as rf
    from bench.fault_injectors import late
    from wandcal.calib.errors import CalibrationError
    from wandcal.calib.run.calibrate import calibrate

    if not (shared_data / rf.CPP_SAMPLE).is_dir():
        pytest.skip("the easyWand C++ sample is absent")
    session = late(rf.LOADERS["cpp"](), 0, -0.5)
    with pytest.raises(CalibrationError) as refused:
        calibrate(session.rig, session.wand, None, points=session.points, axis=session.axis)
    message = str(refused.value)
    assert message.startswith("cam1 is out of time") and "whole frames only" in message and NO_SYNC_ADVICE in message
    assert "calibrate with --sync auto" not in message
