import pytest

from calib.scenes import prepared_scene


@pytest.fixture(scope="module")
def small_rig():
    return prepared_scene()
