"""The start: each camera's first pose, the wand's ends labelled, and the world frame.

| module | holds |
|---|---|
| :mod:`~wandcal.calib.start.offsets` | whole-frame time offsets of untriggered cameras, from the wand itself and from timestamps |
| :mod:`~wandcal.calib.start.markerlabels` | the blobs of a collinear multi-marker wand labelled |
| :mod:`~wandcal.calib.start.planarlabels` | the blobs of a planar wand (a T) labelled from its layout |
| :mod:`~wandcal.calib.start.static` | the static object (L-frame) identified in each camera, its pose by PnP |
| :mod:`~wandcal.calib.start.chain` | the camera graph: which cameras share wand frames and point tracks |
| :mod:`~wandcal.calib.start.resection` | one camera placed against the points the placed cameras triangulate |
| :mod:`~wandcal.calib.start.initial` | every camera's first pose, from the static object or the wand alone |
| :mod:`~wandcal.calib.start.labels` | the wand's two ends told apart across cameras |
| :mod:`~wandcal.calib.start.world` | the result's world frame: static object, axis points, floor, gravity or wand volume |
| :mod:`~wandcal.calib.start.vertical` | the world's vertical from floor points (a plane) or a dropped object (gravity), with its own sigma |
| :mod:`~wandcal.calib.start.degenerate` | captures that cannot calibrate, told apart before the solve |
"""
