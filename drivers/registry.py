"""Choose drivers by URL (pyserial ``serial_for_url`` style).

    v4l2:///dev/video0[?id=cam1&trigger=trigger_mode=1]
    opencv:0 | opencv:/path/video.avi | opencv:/path/frame_%06d.png
    replay:///path/to/capture[?rate=recorded&phase=static]
    sim://?cameras=4&seed=1[&frames=300&drop=cam2:17]   (options and their limits: drivers/sim.py)

One URL may stand for several cameras (a replayed capture, a simulated rig), so
:func:`open_cameras` returns a list.
"""

from __future__ import annotations

from pathlib import Path
from urllib.parse import parse_qsl, urlsplit

from wandcal.drivers.camera import CameraDriver
from wandcal.drivers.errors import CameraUrlError

SCHEMES = ("v4l2", "opencv", "replay", "sim")
# the query options each driver reads: any other is a typo, refused rather than silently ignored
OPTIONS = {
    "sim": ("cameras", "seed", "frames", "static", "drop", "noise", "lframe", "bits", "take", "move"),
    "replay": ("rate", "phase", "cameras"),
    "v4l2": ("id", "trigger"),
    "opencv": ("id", "trigger"),
}
__all__ = ["SCHEMES", "CameraUrlError", "open_cameras"]  # CameraUrlError lives in errors (sim.py raises it too)


def open_cameras(url: str) -> list[CameraDriver]:
    """The camera drivers named by ``url`` (not yet opened: use them in ``with``)."""
    parts = urlsplit(url)
    scheme = parts.scheme.lower()
    query = dict(parse_qsl(parts.query, keep_blank_values=True))
    path = parts.path  # not unquoted: an image-sequence pattern holds printf "%06d"
    _check_options(url, scheme, query)
    if scheme == "sim":
        from wandcal.drivers.sim import open_sim

        return list(open_sim(url, query))
    if scheme == "replay":
        from wandcal.drivers.replay import open_replay

        return list(open_replay(url, path, query))
    if scheme in ("v4l2", "opencv"):
        return [_open_cv(url, scheme, path, query)]
    raise CameraUrlError(
        f"unknown camera URL {url!r}: the scheme must be one of {', '.join(s + ':' for s in SCHEMES)} "
        "(e.g. v4l2:///dev/video0, opencv:0, replay:///path/to/capture, sim://?cameras=4)"
    )


def _check_options(url: str, scheme: str, query: dict[str, str]) -> None:
    """Refuse a query option the driver does not read (``sim://?sed=2`` would record seed 0)."""
    import difflib

    known = OPTIONS.get(scheme)
    if known is None:
        return  # an unknown scheme: open_cameras says which there are
    for key in query:
        if key not in known:
            close = difflib.get_close_matches(key, known, n=1)
            raise CameraUrlError(f"{url}: unknown option {key!r}" + (f"; did you mean {close[0]}?" if close else "")
                                 + f" ({scheme}: reads {', '.join(known)})")


def _open_cv(url: str, scheme: str, path: str, query: dict[str, str]) -> CameraDriver:
    import cv2

    from wandcal.drivers.opencv import OpenCVCamera

    if not path:
        raise CameraUrlError(f"{url}: no device or file; write e.g. v4l2:///dev/video0 or opencv:0")
    source: int | str
    if scheme == "v4l2":
        source, api = path, cv2.CAP_V4L2
        default_id = Path(path).name
    elif path.isdigit():
        source, api, default_id = int(path), cv2.CAP_ANY, f"cam{path}"
    else:
        # a printf pattern is an image sequence, which only the CAP_IMAGES backend reads
        source, api = path, (cv2.CAP_IMAGES if "%" in path else cv2.CAP_ANY)
        default_id = Path(path).stem.split("%")[0].rstrip("_-") or "cam0"
    return OpenCVCamera(query.get("id", default_id), url, source, api, query.get("trigger"))
