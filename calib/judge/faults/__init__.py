"""The fault finders: which camera disagrees with the others, and why.

Each one looks for one kind of fault with the result's poses held; the verdict
(:mod:`~wandcal.calib.judge.verdict`) and the run layer (:mod:`~wandcal.calib.run.judgement`)
put what they find in order.

| module | holds |
|---|---|
| :mod:`~wandcal.calib.judge.faults.screen` | why one camera disagrees: its timing (:class:`TimingFault`), its lens, or else |
| :mod:`~wandcal.calib.judge.faults.leave_one_out` | rigs of 3-5 cameras: each camera against the points the others triangulate (lens) |
| :mod:`~wandcal.calib.judge.faults.swapped` | rigs of 3-5 cameras: two cameras whose observations fit better with each other's intrinsics (columns swapped) |
| :mod:`~wandcal.calib.judge.faults.own_errors` | the points eliminated: each camera's own noise (rigs of any size; a large one on a bounded number of views) |
| :mod:`~wandcal.calib.judge.faults.pose_steps` | the points eliminated: a step in a camera's pose, tested in full, and the turn the test can name |
| :mod:`~wandcal.calib.judge.faults.rejected_runs` | a knock the outlier pass rejected: a camera's rejected camera-frames bunched at one end of its time, one turn bringing them back |
| :mod:`~wandcal.calib.judge.faults.step_columns` | the pose-step test's columns with the points projected out: a camera's pose, every camera's lens, another camera's two poses |
| :mod:`~wandcal.calib.judge.faults.f_distribution` | the F distribution's upper tail and its critical values, for the F and Hotelling tests, without SciPy |
| :mod:`~wandcal.calib.judge.faults.moved` | which camera moved, from every camera's step test (left out, and beside each other camera's move), and its fault; a large rig's cameras screened cheaply first |
| :mod:`~wandcal.calib.judge.faults.timing_pairs` | a camera out of time, found from every pair of cameras (whole-frame shift, then its fraction) |
| :mod:`~wandcal.calib.judge.faults.epipolar_pairs` | its evidence: every pair of cameras' samples at the same time, as epipolar products |
| :mod:`~wandcal.calib.judge.faults.start_timing` | a start refused because a camera is out of time: the shift that places it, named with ``--sync auto`` |
"""
