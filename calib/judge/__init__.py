"""Judgement: how good a calibration is, and what to do when it is not.

| module | holds |
|---|---|
| :mod:`~wandcal.calib.judge.quality` | residuals per camera, worst frames, wand-length spread, outliers |
| :mod:`~wandcal.calib.judge.coverage` | where in each image the wand was seen |
| :mod:`~wandcal.calib.judge.residuals` | every camera's residuals on the same observations, whichever method solved |
| :mod:`~wandcal.calib.judge.verdict` | the verdict per camera and for the rig, with reasons and advice |
| :mod:`~wandcal.calib.judge.placement` | the world frame's verdict: its placement against the volume, its object's faults |
| :mod:`~wandcal.calib.judge.sanity` | the checks every method's result must pass before it is written |
| :mod:`~wandcal.calib.judge.faults` | the fault finders: which camera is at fault and how (timing, lens, noise, a move during the capture) |
| :mod:`~wandcal.calib.judge.evaluate` | fixed cameras judged against a capture: residuals, wand lengths, points (the report) |
| :mod:`~wandcal.calib.judge.bumps` | did a camera move? each one against a fresh capture's wand ends and points (``wandcal check``), a knock told from another rig |
| :mod:`~wandcal.calib.judge.intrinsic_limits` | the honest sigma: each camera's centre per 1% of a focal length and per sigma of each other intrinsic given, not refined |
| :mod:`~wandcal.calib.judge.limit_words` | the verdict's limits in words: each camera's dominant given intrinsics, by how much and what to do (the CLI summary and the report's page) |
| :mod:`~wandcal.calib.judge.lens_sigmas` | the principal point's and the distortion's assumed sigmas (measured on real lenses), and how the observations move with each |
| :mod:`~wandcal.calib.judge.crb` | the Cramér-Rao bound of the poses, for tests and benchmarks |
"""
