"""Judgement: how good a calibration is, and what to do when it is not.

| module | holds |
|---|---|
| :mod:`~wandcal.calib.judge.quality` | residuals per camera, worst frames, wand-length spread, outliers |
| :mod:`~wandcal.calib.judge.coverage` | where in each image the wand was seen |
| :mod:`~wandcal.calib.judge.residuals` | every camera's residuals on the same observations, whichever method solved |
| :mod:`~wandcal.calib.judge.faults` | why one camera disagrees: its timing (:class:`TimingFault`), its lens, or else |
| :mod:`~wandcal.calib.judge.verdict` | the verdict per camera and for the rig, with reasons and advice |
| :mod:`~wandcal.calib.judge.evaluate` | fixed cameras judged against a capture: residuals, wand lengths, points (the report) |
| :mod:`~wandcal.calib.judge.bumps` | did a camera move? each one against a fresh capture's wand ends and points (``wandcal check``), a knock told from another rig |
| :mod:`~wandcal.calib.judge.leave_one_out` | rigs of 3-5 cameras: each camera against the points the others triangulate (lens) |
| :mod:`~wandcal.calib.judge.own_errors` | the points eliminated: each camera's own noise (rigs of any size; a large one on a bounded number of views) |
| :mod:`~wandcal.calib.judge.pose_steps` | the points eliminated: a step in a camera's pose (moved); a large rig's cameras screened cheaply, the suspects tested in full |
| :mod:`~wandcal.calib.judge.intrinsic_limits` | the honest sigma: each camera's centre per 1% of a focal length given, not refined |
| :mod:`~wandcal.calib.judge.timing_pairs` | a camera out of time, found from every pair of cameras (whole-frame shift, then its fraction) |
| :mod:`~wandcal.calib.judge.start_timing` | a start refused because a camera is out of time: the shift that places it, named with ``--sync auto`` |
| :mod:`~wandcal.calib.judge.crb` | the Cramér-Rao bound of the poses, for tests and benchmarks |
"""
