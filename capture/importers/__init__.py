"""Importers: other tools' calibration sessions as ``wandcal-capture/1`` captures (docs/import.md).

| module | reads |
|---|---|
| :mod:`capture.importers.easywand` | easyWand's saved session (``*_easyWandData.mat``) or its input files |
| :mod:`capture.importers.argus` | Argus Wand's inputs: ``*-xypts.csv`` files and a camera profile |
| :mod:`capture.importers.svoboda` | a MultiCamSelfCal folder (``points.dat``, ``IdMat.dat``, ``Res.dat``, ``*.rad``) |
| :mod:`capture.importers.dltdv` | what easyWand and Argus share: profile rows, xypts tables, y-up pixels |
| :mod:`capture.importers.summary` | :class:`Imported` (the capture and what could not be used) and its printout |

Every importer converts to wandcal's conventions at this edge (docs/conventions.md): pixels with
the origin at the top-left and y down, OpenCV distortion. Bad input raises
:class:`capture.folder.CaptureFormatError` naming the file, the line or field, and what to do.
"""

from capture.importers.summary import Imported, summary_lines

__all__ = ["Imported", "summary_lines"]
