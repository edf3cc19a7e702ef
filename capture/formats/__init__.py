"""Camera formats, both ways: results exported in other tools' camera formats (docs/formats.md),
and those formats read back as a rig (``wandcal import cameras``).

| module | reads or writes |
|---|---|
| :mod:`wandcal.capture.formats.export` | :func:`export`: a result in any camera format below, by name |
| :mod:`wandcal.capture.formats.cameras_in` | any camera format ``wandcal export`` writes, read back as a rig (``wandcal import cameras``) |
| :mod:`wandcal.capture.formats.cameras` | :class:`PosedCameras`, what every camera format writes and reads back |
| :mod:`wandcal.capture.formats.anipose_opencv` | anipose ``calibration.toml`` and OpenCV YAML |
| :mod:`wandcal.capture.formats.opencv_yaml` | OpenCV's YAML read without OpenCV (whose parser aborts on damaged files) |
| :mod:`wandcal.capture.formats.dlt` | DLT coefficients (DLTdv, easyWand, Argus) |
| :mod:`wandcal.capture.formats.qualisys_vicon` | Qualisys ``.qca`` and Vicon ``.xcp`` |
| :mod:`wandcal.capture.formats.openptv` | OpenPTV's ptv.par, ``.ori``, ``.addpar`` and ``_targets`` (read only): cameras behind a flat window |

Other tools' whole sessions (cameras and wand or point tracks) are imported as captures by
:mod:`wandcal.capture.importers`. Bad input raises :class:`wandcal.capture.folder.CaptureFormatError`
naming the file, the line or field, and what to do.
"""
