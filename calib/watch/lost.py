"""A camera knocked too far to follow: its blobs are no longer where the markers project.

The pose test (:mod:`wandcal.calib.watch.sequential`) reads a camera's residuals, and a residual
needs the camera's blob within :data:`wandcal.calib.watch.health.HEALTH_PX` of the marker the
others triangulate. A camera turned further (1 deg at f = 1700 px is 30 px) finds none of its
markers: its residuals stop, and the pose test sees nothing. What changes is the share of the markers
it finds. Over its baseline windows a camera finds a share q0 of the markers projected into it;
for each start k among the last :data:`GLR_WINDOWS` windows, x found of m projected gives the
binomial log-likelihood ratio of a share x/m against q0,
``S_k = 2 [x ln(x / (m q0)) + (m - x) ln((m - x) / (m (1 - q0)))]``, and the test alarms when the share
fell under :data:`LOST_SHARE` of q0 with ``S_k`` past :data:`LOST_THRESHOLD` (chi-square with one
degree of freedom: a tail of 3e-9, as the pose test's).

A camera whose view is blocked (a person in front of it, its light off) also finds few markers,
but it has few blobs: the camera must still hold at least :data:`BLOBS_SHARE` of the blobs it
would need for its baseline share, so a blocked camera is not called moved.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import xlogy

from wandcal.calib.watch.sequential import BASELINE_WINDOWS, GLR_WINDOWS

LOST_SHARE = 0.25  # found under a quarter of its baseline share: not occlusion by a marker or two
LOST_THRESHOLD = 35.0  # chi2_1 tail 3e-9
BLOBS_SHARE = 0.5  # its blobs: at least half the markers its baseline share would find
MIN_PROJECTED = 30  # markers projected into it since the start: fewer say nothing


@dataclass
class FoundTest:
    """The running found-share test of one camera: per window, markers found, projected, and the camera's blobs."""

    found: list[float] = field(default_factory=list)
    projected: list[float] = field(default_factory=list)
    blobs: list[float] = field(default_factory=list)
    start: list[int] = field(default_factory=list)

    def add(self, found: float, projected: float, blobs: float, start: int) -> None:
        self.found.append(found)
        self.projected.append(projected)
        self.blobs.append(blobs)
        self.start.append(start)

    def mark(self) -> int:
        return len(self.found)

    def rewind(self, windows: int) -> None:
        for values in (self.found, self.projected, self.blobs, self.start):
            del values[windows:]

    def glr(self) -> tuple[float, int]:
        """(the largest S_k of a fall, the first frame of its window) over the last windows; (0, -1) when none."""
        end = len(self.found)
        first = max(BASELINE_WINDOWS, end - GLR_WINDOWS)
        m0 = sum(self.projected[:BASELINE_WINDOWS])
        if end <= first or m0 < MIN_PROJECTED:
            return 0.0, -1
        q0 = float(np.clip(sum(self.found[:BASELINE_WINDOWS]) / m0, 1e-3, 1 - 1e-3))
        x = np.cumsum(np.array(self.found[first:end])[::-1])[::-1]
        m = np.cumsum(np.array(self.projected[first:end])[::-1])[::-1]
        b = np.cumsum(np.array(self.blobs[first:end])[::-1])[::-1]
        q = x / np.maximum(m, 1)
        S = 2 * (xlogy(x, q / q0) + xlogy(m - x, (1 - q) / (1 - q0)))
        fell = (m >= MIN_PROJECTED) & (q < LOST_SHARE * q0) & (b >= BLOBS_SHARE * q0 * m)
        S = np.where(fell, S, 0.0)
        k = int(np.argmax(S))
        return float(S[k]), self.start[first + k]
