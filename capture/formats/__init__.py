"""Other tools' formats, both ways: their sessions imported as ``wandcal-capture/1`` captures
(docs/import.md), and results exported in their camera formats (docs/formats.md).

| module | reads or writes |
|---|---|
| :mod:`wandcal.capture.formats.easywand` | easyWand's saved session (``*_easyWandData.mat``) or its input files |
| :mod:`wandcal.capture.formats.argus` | Argus Wand's inputs: ``*-xypts.csv`` files and a camera profile |
| :mod:`wandcal.capture.formats.svoboda` | a MultiCamSelfCal folder (``points.dat``, ``IdMat.dat``, ``Res.dat``, ``*.rad``) |
| :mod:`wandcal.capture.formats.dltdv` | what easyWand and Argus share: profile rows, xypts tables, y-up pixels |
| :mod:`wandcal.capture.formats.anipose` | anipose / Pose2Sim sessions: ``calibration.toml`` and the 2D keypoints |
| :mod:`wandcal.capture.formats.deeplabcut` | 2D keypoints from DeepLabCut CSVs and aniposelib points arrays |
| :mod:`wandcal.capture.formats.summary` | :class:`Imported` (the capture and what could not be used) and its printout |
| :mod:`wandcal.capture.formats.export` | :func:`export`: a result in any camera format below, by name |
| :mod:`wandcal.capture.formats.cameras_in` | any camera format ``wandcal export`` writes, read back as a rig (``wandcal import cameras``) |
| :mod:`wandcal.capture.formats.cameras` | :class:`PosedCameras`, what every camera format writes and reads back |
| :mod:`wandcal.capture.formats.anipose_opencv` | anipose ``calibration.toml`` and OpenCV YAML |
| :mod:`wandcal.capture.formats.dlt` | DLT coefficients (DLTdv, easyWand, Argus) |
| :mod:`wandcal.capture.formats.qualisys_vicon` | Qualisys ``.qca`` and Vicon ``.xcp`` |

Every importer converts to wandcal's conventions at this edge (docs/conventions.md): pixels with
the origin at the top-left and y down, OpenCV distortion. Bad input raises
:class:`wandcal.capture.folder.CaptureFormatError` naming the file, the line or field, and what to do.
"""

from wandcal.capture.formats.summary import Imported, summary_lines

__all__ = ["Imported", "summary_lines"]
