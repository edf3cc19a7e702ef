"""Pure computation for wand calibration: geometry, initialisation, refinement, reports.

Nothing in this package touches hardware, files or the network; see ``docs/conventions.md``.
"""

from calib.errors import CalibrationError
from calib.rig import Camera, Rig, StaticObservations, WandObservations

__all__ = ["CalibrationError", "Camera", "Rig", "StaticObservations", "WandObservations"]
