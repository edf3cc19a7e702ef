"""What the wanding guidance counts as enough, and how its fast solve is sized."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.judge.coverage import GRID
from wandcal.calib.solve.sync import SYNC_MODES

# Motive's "exceptional" wanding result is a mean 3D error under ~0.5 mm on a room-sized volume;
# wandcal's simulated 8-camera ring reaches it after ~400 well-spread frames (docs/benchmarks.md).
DEFAULT_TARGET_STD_MM = 0.5
# Half of the 8 x 8 cells: the wand has then reached every third of a typical view, which is what
# keeps the lens distortion and the pose from trading off against each other.
DEFAULT_MIN_COVERAGE = 0.5
# Frames per camera in the fast solve: at 400 the scaled sigma is within 3% of the full solve's
# and an update of 16 cameras takes ~0.15 s (docs/decisions/0010-guidance-uncertainty.md).
DEFAULT_FRAMES_PER_CAMERA = 400
# A camera enters the solve with this many frames shared with another camera, or seen by two
# cameras already in the solve (decision 0095): with fewer its pose is the initial guess of a handful
# of correspondences, not a measurement (wandcal.calib.start.chain needs 10 correspondences, i.e. 5
# frames, to place a pair at all).
MIN_SOLVE_FRAMES = 10
# Levenberg-Marquardt steps of the fast solve at most, from the start's poses (or the last update's):
# the predicted sigma is the information at the estimate, which needs the poses near the optimum,
# not converged to STOP_SE. At 128 x 3000 (ring, hallway, dome, tiers) calibrate's ba takes 10
# steps; after 3 each camera's sigma is within 2% of the converged solve's and as close to
# calibrate's as that (decision 0107); after 2 it is 3.5% off (after 1, 11%).
SOLVE_STEPS = 3


@dataclass(frozen=True)
class GuidanceSettings:
    """What counts as enough, and how the fast solve is sized.

    Args:
        target_std_mm: every camera's predicted centre 1-sigma must be below this, millimetres.
        min_coverage: every camera's covered share of its image grid must reach this, in [0, 1].
        frames_per_camera: frames each camera keeps in the fast solve (the rest are subsampled away).
        grid: (rows, columns) of the coverage grid over each image.
        sync: ``"none"`` (a trigger's capture: a camera out of time is a fault to mend) or
            ``"auto"`` (cameras without a trigger: each update finds their whole-frame offsets
            as ``wandcal calibrate --sync auto`` does and judges the frames realigned).
    """

    target_std_mm: float = DEFAULT_TARGET_STD_MM
    min_coverage: float = DEFAULT_MIN_COVERAGE
    frames_per_camera: int = DEFAULT_FRAMES_PER_CAMERA
    grid: tuple[int, int] = GRID
    sync: str = "none"

    def __post_init__(self) -> None:
        if self.sync not in SYNC_MODES:
            raise CalibrationError(f"guidance sync must be one of {', '.join(SYNC_MODES)}, got {self.sync!r}")
        if not (np.isfinite(self.target_std_mm) and self.target_std_mm > 0):
            raise CalibrationError(f"guidance target_std_mm must be a positive number of millimetres, got {self.target_std_mm!r}")
        if not 0.0 <= self.min_coverage <= 1.0:
            raise CalibrationError(f"guidance min_coverage must lie in [0, 1], got {self.min_coverage!r}")
        if self.frames_per_camera < MIN_SOLVE_FRAMES:
            raise CalibrationError(f"guidance frames_per_camera must be at least {MIN_SOLVE_FRAMES}, "
                                   f"got {self.frames_per_camera!r}")
        if len(self.grid) != 2 or min(self.grid) < 1:
            raise CalibrationError(f"guidance grid must be (rows, columns) of at least 1, got {self.grid!r}")
