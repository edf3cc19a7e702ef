"""Cameras without a common trigger: each camera's sub-frame time offset (and drift) fitted with
the poses, by resampling its own wand track in time (docs/sync.md). The whole-frame search that
starts it is :mod:`wandcal.calib.start.offsets.whole_frames`.

| module | holds |
|---|---|
| :mod:`~wandcal.calib.solve.sync.fit` | :func:`fit_timing`, :func:`resample`: the offsets' Gauss-Newton fit |
| :mod:`~wandcal.calib.solve.sync.normal` | that fit's normal equations, the wand ends eliminated, each camera weighed by its noise |
| :mod:`~wandcal.calib.solve.sync.report` | :func:`sync_report`: the result's ``sync`` section and its warnings; the ``--sync`` modes |
| :mod:`~wandcal.calib.solve.sync.joint` | :class:`TimeColumns`: the offsets refined again inside ``ba``, over every frame |
| :mod:`~wandcal.calib.solve.sync.tracks` | each camera's wand track as a function of time, interpolated between its frames |
"""

from wandcal.calib.solve.sync.fit import Timing, fit_timing, resample, spread_frames, zero_timing
from wandcal.calib.solve.sync.joint import TimeColumns
from wandcal.calib.solve.sync.report import DEFAULT_SYNC, SYNC_MODES, sync_report
from wandcal.calib.solve.sync.tracks import Tracks

__all__ = ["DEFAULT_SYNC", "SYNC_MODES", "Timing", "TimeColumns", "Tracks", "fit_timing", "resample", "spread_frames", "sync_report",
           "zero_timing"]
