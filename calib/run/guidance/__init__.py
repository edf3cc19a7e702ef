"""Wanding guidance: where each camera still needs the wand, and whether the operator can stop.

:func:`wanding_guidance` turns the wand blobs recorded so far into a document
(``wandcal-guidance/1``, docs/api.md) that says, per camera, how many frames saw both wand ends,
how much of its image the wand has covered (:mod:`wandcal.calib.judge.coverage`), how many frames it shares
with each other camera, and the predicted 1-sigma of its centre from a fast ``ba`` solve; then
whether that is ``enough``, and what to do next, worst camera first.

The predicted sigma is each camera's centre *relative to the rest of the rig*: the solve's pose
covariance (``sigma^2 (J^T J)^-1``, calib/solve/uncertainty.py) carried into the frame that best fits
every camera's centre and a point one metre along its optical axis, each camera weighted by how
well it is known. That is the part of the error that waving reduces. The result's
``center_std_mm`` is in the user's world frame and adds the L-frame's own noise, which no amount
of waving removes (docs/decisions/0010-guidance-uncertainty.md has the measurements).

Fast and honest: each camera keeps about ``frames_per_camera`` of its frames (drawn the same way
at every update, so the estimate does not jitter) and its sigma is scaled by
sqrt(kept / all) -- information adds up over frames, so the full capture's sigma is the
subsample's shrunk by that ratio (measured within 3% at 8 x 1500 and 16 x 2500, in the decision).
The solve takes at most ``SOLVE_STEPS`` (3) Levenberg-Marquardt steps and reads the information there:
a sigma needs poses near the optimum, not converged ones (within 2% of the converged solve's at
128 x 3000, decision 0107). The last solution starts the next solve (:class:`Solution`), which skips the initial poses; when
cameras joined the solve since, the start places only them. A camera joins the solve with 10 frames
shared with another camera, or seen by two cameras already in it (decision 0095).
"""

from wandcal.calib.run.guidance.document import GUIDANCE_FORMAT, SILENT_CAMERA_FRAMES
from wandcal.calib.run.guidance.settings import (
    DEFAULT_FRAMES_PER_CAMERA,
    DEFAULT_MIN_COVERAGE,
    DEFAULT_TARGET_STD_MM,
    MIN_SOLVE_FRAMES,
    GuidanceSettings,
)
from wandcal.calib.run.guidance.update import (
    NO_WAND_YET,
    Guidance,
    Solution,
    relative_uncertainty,
    subsample,
    wanding_guidance,
)

__all__ = [
    "DEFAULT_FRAMES_PER_CAMERA", "DEFAULT_MIN_COVERAGE", "DEFAULT_TARGET_STD_MM", "GUIDANCE_FORMAT", "MIN_SOLVE_FRAMES",
    "NO_WAND_YET", "SILENT_CAMERA_FRAMES", "Guidance", "GuidanceSettings", "Solution", "relative_uncertainty",
    "subsample", "wanding_guidance",
]
