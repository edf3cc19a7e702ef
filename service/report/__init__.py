"""``wandcal report``: an illustrated calibration report, an ``index.html`` with PNG figures.

matplotlib comes with wandcal (a core dependency); should it be missing from an environment all
the same, :func:`write_report` raises :class:`ReportUnavailable` and says how to install it.
"""

from __future__ import annotations

import re
from pathlib import Path

from wandcal.capture.folder import Capture
from wandcal.capture.result_file import ResultFile

INDEX = "index.html"
RIG_PNG = "rig.png"
WAND_PNG = "wand-length.png"
INSTALL_HINT = "pip install matplotlib (a dependency of wandcal: reinstall wandcal, or install it alone)"
# a report's file names: what write_report makes, and all the service serves from a report folder
FILE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,120}\.(png|html)$")
_UNSAFE = re.compile(r"[^A-Za-z0-9_-]+")
ID_CHARS = 40  # of a camera id kept in its figure's file name (the index keeps names unique)


class ReportUnavailable(RuntimeError):
    """matplotlib is not installed."""


def require_matplotlib() -> None:
    """Raise :class:`ReportUnavailable` with the install hint when matplotlib cannot be imported."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise ReportUnavailable(f"the report draws its figures with matplotlib, which is not installed; "
                                f"{INSTALL_HINT}") from None


def camera_png(index: int, camera_id: str) -> str:
    """A camera figure's file name: its position and a file-safe form of its id."""
    return f"camera-{index + 1:02d}-{_UNSAFE.sub('_', camera_id)[:ID_CHARS]}.png"


def write_report(result: ResultFile, capture: Capture | None, out_dir: str | Path) -> list[Path]:
    """Draw the figures and write the page into ``out_dir`` (created if needed).

    Args:
        result: a read ``wandcal-result/1`` file (:func:`wandcal.capture.result_file.read_result`).
        capture: the capture the result was calibrated from, or None: then only the rig and the
            tables are drawn, and the page says what needs the capture.
        out_dir: the report's folder.

    Returns:
        The files written, ``index.html`` first.

    Raises:
        ReportUnavailable: matplotlib is not installed.
        CaptureFormatError: the capture is not the one the result came from.
    """
    require_matplotlib()
    from wandcal.service.report import figures
    from wandcal.service.report.analysis import analyse
    from wandcal.service.report.page import render_page

    data = analyse(result, capture)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    names = {"rig": RIG_PNG}
    written = [figures.rig_figure(data, out / RIG_PNG)]
    if len(data.wand_frames):
        names["wand"] = WAND_PNG
        written.append(figures.wand_figure(data, out / WAND_PNG))
    if data.has_capture:
        for cam in data.cameras:
            names[cam.id] = camera_png(cam.index, cam.id)
            written.append(figures.camera_figure(cam, out / names[cam.id]))
    index = out / INDEX
    index.write_text(render_page(data, names), encoding="utf-8")
    return [index, *written]
