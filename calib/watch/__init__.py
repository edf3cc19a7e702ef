"""Watching ordinary takes with a standing calibration (issue 36): a take's unlabelled blobs
(``take``), matched across cameras and triangulated (``match``), each camera's residual against
the markers the others triangulate (``health``), a sequential test that names a moved camera and
tells a drift from a knock (``sequential``), the moved camera re-solved from the take's markers
(``recover``), and the whole of it over a take (``watch``)."""
