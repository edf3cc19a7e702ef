"""Given intrinsics a few per cent off, as real ones are (``wandcal simulate --intrinsics-error``).

The simulator films its wand with its true cameras; a real lab gives rig.json's intrinsics from a
lens's nominal focal length or a calibration of another day, one to a few per cent off (the
published eWand session's refined focal lengths lie 1.2-2.6% above its own yaml files;
docs/verdict.md, "The honest sigma"). :func:`off_intrinsics` draws each camera's given intrinsics
off the truth by stated sigmas, from a stream of its own (the capture's blobs stay those of the
same ``--seed``); the truth keeps the true cameras (:attr:`wandcal.calib.sim.simulate.Truth.cameras`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from wandcal.calib.rig import PINHOLE, Camera, Rig
from wandcal.calib.sim.simulate import SimulatedCapture

INTRINSICS_STREAM = 17  # the draws' own random stream beside the capture's seed


@dataclass(frozen=True)
class IntrinsicsError:
    """The sigmas each camera's given intrinsics are drawn off the truth by (1 sigma, Gaussian).

    focal_rel: the focal length's relative sigma (0.02 is 2%; fx and fy move together, as a lens's
    focal length does); principal_px: each of cx, cy, pixels; distortion: k1 and k2, absolute;
    tangential: (pinhole) p1 and p2, absolute, None: ``distortion`` too (real lenses' p1, p2 are
    known to some 0.0007, their k1, k2 to 0.02-0.08: docs/verdict.md, "The honest sigma");
    write_std: also write each camera's ``focal_std_px`` as ``focal_rel`` times its given focal
    length (the sigma it was drawn from), as a lens calibration would state it."""

    focal_rel: float = 0.0
    principal_px: float = 0.0
    distortion: float = 0.0
    write_std: bool = False
    tangential: float | None = None

    @property
    def any(self) -> bool:
        """Whether anything is drawn off the truth (or a sigma written)."""
        return bool(self.focal_rel or self.principal_px or self.distortion or self.tangential or self.write_std)


def off_camera(cam: Camera, error: IntrinsicsError, rng: np.random.Generator) -> Camera:
    """``cam`` with its intrinsics drawn off by ``error``'s sigmas: four draws (focal, cx, cy and
    four distortion terms) a camera whatever the sigmas, so one sigma's draws do not depend on
    another's being zero."""
    focal, centre, dist = rng.standard_normal(), rng.standard_normal(2), rng.standard_normal(4)
    K = np.array(cam.K, dtype=float)
    scale = 1.0 + error.focal_rel * focal
    K[0, 0] *= scale
    K[1, 1] *= scale
    K[0, 1] *= scale
    K[:2, 2] += error.principal_px * centre
    d = np.array(cam.dist, dtype=float)
    tangential = error.distortion if error.tangential is None else error.tangential
    d[:2] += error.distortion * dist[:2]  # k1, k2 (a fisheye's too)
    if cam.model == PINHOLE:
        d[2:4] += tangential * dist[2:4]  # p1, p2
    std = float(error.focal_rel * K[0, 0]) if error.write_std and error.focal_rel > 0 else cam.focal_std_px
    return replace(cam, K=K, dist=d, focal_std_px=std)


def off_intrinsics(rig: Rig, error: IntrinsicsError, seed: int | None) -> Rig:
    """``rig`` with every camera's given intrinsics off the truth by ``error`` (:func:`off_camera`),
    drawn from the stream ``[seed, INTRINSICS_STREAM]``; ``rig`` itself when nothing is drawn."""
    if not error.any:
        return rig
    rng = np.random.default_rng(None if seed is None else [seed, INTRINSICS_STREAM])
    return replace(rig, cameras=tuple(off_camera(cam, error, rng) for cam in rig.cameras))


def with_intrinsics_error(sim: SimulatedCapture, error: IntrinsicsError, seed: int | None) -> SimulatedCapture:
    """``sim`` with its rig's intrinsics off the truth (:func:`off_intrinsics`) and its truth keeping
    the true cameras; ``sim`` itself when nothing is drawn."""
    if not error.any:
        return sim
    rig = off_intrinsics(sim.rig, error, seed)
    return replace(sim, rig=rig, truth=replace(sim.truth, cameras=sim.rig.cameras))
