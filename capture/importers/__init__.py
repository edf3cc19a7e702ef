"""Other tools' sessions imported as ``wandcal-capture/1`` captures (docs/import.md).

| module | reads |
|---|---|
| :mod:`wandcal.capture.importers.easywand` | easyWand's saved session (``*_easyWandData.mat``) or its input files |
| :mod:`wandcal.capture.importers.argus` | Argus Wand's inputs: ``*-xypts.csv`` files and a camera profile |
| :mod:`wandcal.capture.importers.svoboda` | a MultiCamSelfCal folder (``points.dat``, ``IdMat.dat``, ``Res.dat``, ``*.rad``) |
| :mod:`wandcal.capture.importers.dltdv` | what easyWand and Argus share: profile rows, xypts tables, y-up pixels |
| :mod:`wandcal.capture.importers.anipose` | anipose / Pose2Sim sessions: ``calibration.toml`` and the 2D keypoints |
| :mod:`wandcal.capture.importers.deeplabcut` | 2D keypoints from DeepLabCut CSVs and aniposelib points arrays |
| :mod:`wandcal.capture.importers.summary` | :class:`Imported` (the capture and what could not be used) and its printout |

The cameras these sessions carry are read by :mod:`wandcal.capture.formats` (DLT coefficients,
anipose's TOML, OpenCV YAML). Every importer converts to wandcal's conventions at this edge
(docs/conventions.md): pixels with the origin at the top-left and y down, OpenCV distortion. Bad
input raises :class:`wandcal.capture.folder.CaptureFormatError` naming the file, the line or field,
and what to do.
"""

from wandcal.capture.importers.summary import Imported, summary_lines

__all__ = ["Imported", "summary_lines"]
