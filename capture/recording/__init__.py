"""Recording a capture: camera threads, frame sets assembled from trigger pulses, the folder written
as they arrive, and the live guidance computed while it runs.

| module | holds |
|---|---|
| :mod:`~wandcal.capture.recording.session` | ``record``: the trigger, assembly and the recorder |
| :mod:`~wandcal.capture.recording.readers` | one reader thread per camera, detecting its frames' blobs (draining the camera during a free-running pause) |
| :mod:`~wandcal.capture.recording.framesets` | synchronised frame sets from trigger pulses and camera frames |
| :mod:`~wandcal.capture.recording.record` | the ``wandcal-capture/1`` folder written as frame sets arrive |
| :mod:`~wandcal.capture.recording.writer` | bounded-memory image writing |
| :mod:`~wandcal.capture.recording.centroids` | the points level written as it goes |
| :mod:`~wandcal.capture.recording.stamps` | a recording's camera timestamps (``sync.csv``) and frame rate (``capture.json``), read and checked |
| :mod:`~wandcal.capture.recording.camera_rig` | the rig of the cameras a capture opens (rig.json or the simulated scene's) |
| :mod:`~wandcal.capture.recording.live_guidance` | the guidance recomputed in the background while recording |
| :mod:`~wandcal.capture.recording.missed` | what to do about the sets the cameras missed |
"""
