"""``sim://?take=N&move=CAM:FRAME:DEG:MM``: a simulated rig that plays an ordinary take (issue 36)."""

import numpy as np
import pytest

from wandcal.calib.sim.takes import TAKE_STREAM, body_markers
from wandcal.drivers.errors import CameraUrlError
from wandcal.drivers.registry import open_cameras


def test_a_take_plays_the_simulated_bodies_and_the_knock():
    cams = open_cameras("sim://?cameras=4&seed=3&take=12&frames=40&move=cam2:20:0.5:3")
    scene = cams[0].scene
    want = body_markers(40, 12, 5, np.random.default_rng([3, TAKE_STREAM]))
    assert np.array_equal(scene.points(7), want[7])  # wandcal simulate --take's bodies
    for index, moves in ((1, True), (0, False), (2, False)):
        # the frame before the knock and after it, with the markers held where they were
        scene.take[21] = scene.take[19]
        before, after = scene.spots(index, 19)[0], scene.spots(index, 21)[0]
        assert (np.abs(after - before).max() > 1.0) == moves  # 0.5 deg at f ~ 1100 px: ~10 px


@pytest.mark.parametrize("url, said", [("sim://?take=10&move=cam9:1:0.1:1", "move="),
                                       ("sim://?move=cam1:1:0.1:1", "needs a take"),
                                       ("sim://?take=900", "take must be")])
def test_bad_take_options_are_refused_by_name(url, said):
    with pytest.raises(CameraUrlError, match=said):
        open_cameras(url)
