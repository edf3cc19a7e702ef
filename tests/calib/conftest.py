import pytest

from wandcal.calib.sim.scenes import prepared_scene


@pytest.fixture(scope="module")
def small_rig():
    return prepared_scene()
