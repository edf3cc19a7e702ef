"""The checks every method's result must pass before it is written: every camera still holds
observations, the wand has its given length, and no camera stands under the floor of the frame an
object set (a mirrored or flipped world hides behind a low reprojection error)."""

from __future__ import annotations

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.rig import Rig, camera_list

# sanity checks every method's result must pass
WAND_LENGTH_TOLERANCE = 0.05  # the free wand's mean length within 5% of the given length
BELOW_FLOOR_M = 0.0  # a camera centre under the floor (z < 0 in a static object's or axis frame)


def sanity_check(method: str, rig: Rig, cameras: list[dict], wand_report: dict | None, world: dict,
                 centers: np.ndarray) -> list[str]:
    """The checks every method's result must pass. Raises :class:`CalibrationError` when the
    result is not a calibration (a camera left without observations, a wand of the wrong
    length); returns warnings for what may be wrong but is not sure to be (cameras under the
    floor: a mirrored or flipped world hides behind a low reprojection error)."""
    other = "" if method == "ba" else "; try --method ba"
    ids = rig.ids
    empty = [ids[k] for k, c in enumerate(cameras) if c.get("observations", 0) + c.get("point_observations", 0) == 0]
    if empty:
        raise CalibrationError(f"method {method!r} ended with {camera_list(empty, len(ids))} holding no observations (all were "
                               f"dropped as outliers), so those poses are not calibrated{other}")
    if wand_report is not None and rig.wand_length:
        off = wand_report["length_mean_m"] / rig.wand_length - 1
        if abs(off) > WAND_LENGTH_TOLERANCE:
            raise CalibrationError(
                f"method {method!r} ended with a wand of {1000 * wand_report['length_mean_m']:.1f} +- "
                f"{1000 * wand_report['length_std_m']:.1f} mm against the given {1000 * rig.wand_length:.1f} mm "
                f"({off:+.0%}): the cameras do not agree on the wand{other}; check wand.length_m and the intrinsics")
    warnings = []
    if world.get("frame") in ("static_object", "axis"):
        below = [ids[k] for k, C in enumerate(centers) if C[2] < BELOW_FLOOR_M]
        if below:
            what = "the static object's" if world["frame"] == "static_object" else "the axis points'"
            warnings.append(f"{camera_list(below, len(ids))} {'is' if len(below) == 1 else 'are'} below the floor (z < 0) of "
                            f"{what} frame: the world may be mirrored or upside down; check the order of the "
                            "markers in rig.json (z must point up, towards the cameras)")
    return warnings
