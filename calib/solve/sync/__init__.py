"""Cameras without a common trigger: each camera's sub-frame time offset (and drift) fitted with
the poses, by resampling its own wand track in time (docs/sync.md). The whole-frame search that
starts it is :mod:`wandcal.calib.start.frame_offsets`.

| module | holds |
|---|---|
| :mod:`~wandcal.calib.solve.sync.fit` | :func:`fit_timing`, :func:`resample`, :func:`sync_report`: the offsets' Gauss-Newton fit and the result's ``sync`` section |
| :mod:`~wandcal.calib.solve.sync.joint` | :class:`TimeColumns`: the offsets refined again inside ``ba``, over every frame |
| :mod:`~wandcal.calib.solve.sync.tracks` | each camera's wand track as a function of time, interpolated between its frames |
"""

from wandcal.calib.solve.sync.fit import (
    DEFAULT_SYNC,
    SYNC_MODES,
    Timing,
    fit_timing,
    resample,
    spread_frames,
    sync_report,
    zero_timing,
)
from wandcal.calib.solve.sync.joint import TimeColumns
from wandcal.calib.solve.sync.tracks import Tracks

__all__ = ["DEFAULT_SYNC", "SYNC_MODES", "Timing", "TimeColumns", "Tracks", "fit_timing", "resample", "spread_frames", "sync_report",
           "zero_timing"]
