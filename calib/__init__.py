"""Pure computation for wand calibration: geometry, detection, the start, refinement, judgement.

Nothing in this package touches hardware, files or the network; see ``docs/conventions.md`` and,
for the stages and which package may import which, ``docs/architecture.md``.

| module or package | holds |
|---|---|
| :mod:`~wandcal.calib.errors`, :mod:`~wandcal.calib.rig`, :mod:`~wandcal.calib.geometry`, :mod:`~wandcal.calib.observations`, :mod:`~wandcal.calib.triangulate`, :mod:`~wandcal.calib.wandlayout` | the core every stage shares |
| :mod:`~wandcal.calib.refraction` | cameras that look through a flat window into water (OpenPTV's multimedia model) |
| :mod:`~wandcal.calib.detect` | marker blobs in images |
| :mod:`~wandcal.calib.start` | first poses, wand labels, the world frame |
| :mod:`~wandcal.calib.solve` | the refinement methods (``ba``, ``lp``, ``paper``) and their back-ends |
| :mod:`~wandcal.calib.judge` | quality, verdicts, checks against fresh captures |
| :mod:`~wandcal.calib.watch` | ordinary takes watched with a standing calibration: matches, each camera's health, a moved camera named and re-solved (``wandcal watch``) |
| :mod:`~wandcal.calib.run` | the stages run in order: :mod:`~wandcal.calib.run.calibrate`, :mod:`~wandcal.calib.run.refine`, :mod:`~wandcal.calib.run.resolve`, :mod:`~wandcal.calib.run.guidance`, ... |
| :mod:`~wandcal.calib.sim` | simulated rigs and scenes |
"""

from wandcal.calib.errors import CalibrationError
from wandcal.calib.rig import Camera, Rig, StaticObservations, WandObservations

__all__ = ["CalibrationError", "Camera", "Rig", "StaticObservations", "WandObservations"]
