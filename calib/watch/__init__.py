"""Watching ordinary takes with a standing calibration (issue 36, decision 0034).

| module | holds |
|---|---|
| :mod:`~wandcal.calib.watch.take` | a take's unlabelled blobs, and the padded per-frame layout the matcher works on |
| :mod:`~wandcal.calib.watch.match` | blobs matched across cameras along epipolar lines, verified in a third, triangulated |
| :mod:`~wandcal.calib.watch.health` | each camera's residual against the markers the others triangulate, window by window |
| :mod:`~wandcal.calib.watch.sequential` | the window-limited GLR test that names a moved camera; drift or knock |
| :mod:`~wandcal.calib.watch.attribute` | which of several raised cameras moved: each one's move fitted, compared by Vuong's test, or "one of" |
| :mod:`~wandcal.calib.watch.lost` | a camera knocked too far to follow: the share of its markers it finds, against its baseline |
| :mod:`~wandcal.calib.watch.recover` | a moved camera re-solved from the take's markers, the others held |
| :mod:`~wandcal.calib.watch.search` | a moved camera's views of the markers found again, however far it turned (RANSAC on a turn) |
| :mod:`~wandcal.calib.watch.report` | what a watch reports: each camera's health, the take's, the "one of" advice; its frames numbered as the take's |
| :mod:`~wandcal.calib.watch.stream` | all of it over a take as it streams in, batch by batch (``wandcal watch``, the live take) |
| :mod:`~wandcal.calib.watch.refracted` | the matcher's camera model for cameras behind a flat window into water (decision 0048) |
"""
