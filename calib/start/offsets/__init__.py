"""The cameras' whole-frame time offsets, where the sub-frame fit (:mod:`wandcal.calib.solve.sync`) starts.

| module | holds |
|---|---|
| :mod:`~wandcal.calib.start.offsets.whole_frames` | whole-frame time offsets of untriggered cameras, from the wand itself: the order cameras are timed in, and the search over the rig |
| :mod:`~wandcal.calib.start.offsets.shift_search` | one camera's offset among its shifts against cameras already timed, and its refusals |
| :mod:`~wandcal.calib.start.offsets.pair_fit` | one camera pair at one lag: shared frames, the RANSAC pose and the share it fits, midpoint scores |
| :mod:`~wandcal.calib.start.offsets.confirm` | the offsets both wand ends confirm against a camera in time (what a live warning may say) |
| :mod:`~wandcal.calib.start.offsets.timestamps` | whole-frame offsets from timestamps on a shared clock: where the search starts |
"""
