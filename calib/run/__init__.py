"""The run layer: the stages of ``docs/architecture.md`` run in order, and what a run returns.

| module or package | holds |
|---|---|
| :mod:`~wandcal.calib.run.calibrate` | ``calibrate``: observations, sync, start, refine, world frame, figures, judgement |
| :mod:`~wandcal.calib.run.start_steps` | ``calibrate``'s steps up to the refinement's start: observations, whole-frame sync, the start with the static object's poses, sub-frame sync |
| :mod:`~wandcal.calib.run.marker_steps` | a wand of three markers or more: its blobs ordered, every marker labelled, the refinement with the wand model |
| :mod:`~wandcal.calib.run.sparse_offsets` | ``--sync auto`` on sparse rigs: each camera's whole-frame offset against the wand the others triangulate |
| :mod:`~wandcal.calib.run.refine` | the chosen method's refinement and outlier rejection over a built problem (``problem``, ``methods``, ``outliers``) |
| :mod:`~wandcal.calib.run.resolve` | ``solve_only``: re-solve some cameras of a result, the rest held |
| :mod:`~wandcal.calib.run.judgement` | the verdict of a run, from the judge stage's criteria and faults |
| :mod:`~wandcal.calib.run.rig_faults` | the cameras at fault, by the rig's size: few cameras by comparison, many by the suspect screen |
| :mod:`~wandcal.calib.run.own_error_faults` | each camera's own errors with the points eliminated: a camera that moved, a noisy camera, the noise at the limit |
| :mod:`~wandcal.calib.run.camera_reports` | each camera's figures and the result's warnings |
| :mod:`~wandcal.calib.run.options` | ``CalibrationOptions``: one frozen, checked set of options for the CLI, jobs and the worker |
| :mod:`~wandcal.calib.run.result` | ``CalibrationResult``: the wand's, the solver's and the world frame's figures, to and from ``wandcal-result/1`` |
| :mod:`~wandcal.calib.run.camera_figures` | ``CameraFigures``: a camera's pose sigmas, residuals, refined intrinsics and the judgement's reading |
| :mod:`~wandcal.calib.run.guidance` | where to wave next, and whether the capture is enough |
"""
