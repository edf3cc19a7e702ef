"""Write a ``wandcal-result/1`` document in other tools' formats, and read those formats back.

Pure functions from the result dict (plus the rig, for whatever the result leaves out) to text,
and from text to :class:`PosedCameras`. Every format's conventions are stated once, in
docs/formats.md; conversions between conventions happen here, at the edge, and nowhere else.

| format | module | read back by |
|---|---|---|
| ``anipose-toml`` | :mod:`wandcal.capture.formats.anipose_opencv` | :func:`wandcal.capture.formats.anipose_opencv.read_anipose_toml` |
| ``opencv-yaml`` | :mod:`wandcal.capture.formats.anipose_opencv` | :func:`wandcal.capture.formats.anipose_opencv.read_opencv_yaml` |
| ``dlt-csv`` | :mod:`wandcal.capture.formats.dlt` | :func:`wandcal.capture.formats.dlt.read_dlt_csv` (with the image sizes) |
| ``qca`` | :mod:`wandcal.capture.formats.qualisys_vicon` | :func:`wandcal.capture.formats.qualisys_vicon.read_qca` |
| ``xcp`` | :mod:`wandcal.capture.formats.qualisys_vicon` | :func:`wandcal.capture.formats.qualisys_vicon.read_xcp` |
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from wandcal.calib.errors import CalibrationError
from wandcal.calib.rig import Rig
from wandcal.capture.formats import dlt, qualisys_vicon
from wandcal.capture.formats.anipose_opencv import read_anipose_toml, read_opencv_yaml, to_anipose_toml, to_opencv_yaml
from wandcal.capture.formats.cameras import BOTTOM_LEFT, TOP_LEFT, UNITS, PosedCameras, posed_cameras

__all__ = ["BOTTOM_LEFT", "FORMAT_NAMES", "TOP_LEFT", "UNITS", "Format", "PosedCameras", "export", "formats",
           "posed_cameras", "read_anipose_toml", "read_opencv_yaml", "to_anipose_toml", "to_opencv_yaml"]

@dataclass(frozen=True)
class Format:
    """An exchange format: its writer, and the units and pixel origins it can be written in (the
    first of each is the default)."""

    name: str
    write: Callable[..., str]
    units: tuple[str, ...]
    origins: tuple[str, ...]


def formats() -> dict[str, Format]:
    """Every format by name (docs/formats.md)."""
    return {f.name: f for f in (
        Format("anipose-toml", to_anipose_toml, ("m", "mm"), (TOP_LEFT,)),
        Format("opencv-yaml", to_opencv_yaml, ("m", "mm"), (TOP_LEFT,)),
        # DLTdv, easyWand and Argus, the tools that read DLT coefficients, put y up (decision 0009)
        Format("dlt-csv", dlt.to_dlt_csv, ("m", "mm"), (BOTTOM_LEFT, TOP_LEFT)),
        Format("qca", qualisys_vicon.to_qca, ("mm",), (TOP_LEFT,)),
        Format("xcp", qualisys_vicon.to_xcp, ("mm",), (TOP_LEFT,)),
    )}


FORMAT_NAMES = ("anipose-toml", "opencv-yaml", "dlt-csv", "qca", "xcp")


def export(result: dict, fmt: str, rig: Rig | None = None, unit: str | None = None, origin: str | None = None) -> str:
    """The result in format ``fmt``; ``unit`` and ``origin`` default to the format's own, and a
    choice the format cannot hold is refused with a message saying what it holds."""
    from wandcal.capture.result_file import check_result

    check_result(result, "the result", rig)  # the one reader: every field a writer uses is checked first
    table = formats()
    if fmt not in table:
        raise CalibrationError(f"unknown format {fmt!r}; choose one of {', '.join(table)}")
    f = table[fmt]
    unit = unit or f.units[0]
    if unit not in f.units:
        raise CalibrationError(f"{fmt} writes lengths in {' or '.join(f.units)} only, not {unit!r} (docs/formats.md)")
    origin = origin or f.origins[0]
    if origin not in f.origins:
        raise CalibrationError(f"{fmt} has its pixel origin at the {' or '.join(f.origins)} only, not {origin!r}; "
                               "the pixel origin is a choice for dlt-csv (docs/formats.md)")
    kwargs = {"unit": unit} if len(f.units) > 1 else {}
    if len(f.origins) > 1:
        kwargs["origin"] = origin
    return f.write(result, rig, **kwargs)
