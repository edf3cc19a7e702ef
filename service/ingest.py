"""Frame-set images -> blob centres: decode each camera's image and run the blob detector.

Images are PNG, checked against the rig's image size before they are decoded, so a small file
that claims a huge image cannot make the server allocate it (other formats are refused: their
size cannot be read before decoding).
"""

from __future__ import annotations

import functools
import struct
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

from wandcal.calib.detect.config import DetectConfig
from wandcal.calib.errors import CalibrationError
from wandcal.calib.rig import Camera, Rig, StaticObservations

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# OpenCV's decoders release the GIL, so a frame set's images decode side by side; two threads
# per core keep both cores busy while one thread waits on Python-level work.
DECODE_THREADS = 4


@functools.cache
def _executor() -> ThreadPoolExecutor:
    """The process's one decoding pool, made on first use."""
    return ThreadPoolExecutor(DECODE_THREADS, thread_name_prefix="wandcal-decode")


def png_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from a PNG header, or None if ``data`` is not a PNG."""
    if len(data) < 24 or not data.startswith(PNG_SIGNATURE) or data[12:16] != b"IHDR":
        return None
    return struct.unpack(">II", data[16:24])


def decode_image(data: bytes, camera: Camera) -> np.ndarray:
    """(H, W) uint8/uint16 grey image of ``camera`` from encoded bytes (PNG, TIFF, JPEG, ...)."""
    where = f"image for camera {camera.id!r}"
    size = png_size(data)
    if size is None:  # only a PNG's size can be read before decoding: a 200-byte JPEG claiming
        # 30000x30000 pixels made OpenCV allocate 1.7 GB (tests/reliability/test_security.py)
        raise CalibrationError(f"{where} is not a PNG; send PNG images (8 or 16 bit grey), the only format whose "
                               "size the server checks before decoding")
    if size != (camera.width, camera.height):
        raise CalibrationError(
            f"{where} is {size[0]}x{size[1]} but rig.json says {camera.width}x{camera.height}; "
            "send full-resolution frames of that camera"
        )
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) if data else None
    if image is None:
        raise CalibrationError(f"{where} could not be decoded; send a PNG (8 or 16 bit grey)")
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
    if image.shape != (camera.height, camera.width):
        raise CalibrationError(
            f"{where} is {image.shape[1]}x{image.shape[0]} but rig.json says {camera.width}x{camera.height}; "
            "send full-resolution frames of that camera"
        )
    if image.dtype not in (np.uint8, np.uint16):
        raise CalibrationError(f"{where} has pixel type {image.dtype}; send 8- or 16-bit grey images")
    return image


def detect_one(data: bytes, camera: Camera, config: DetectConfig | None = None) -> np.ndarray:
    """(K, 2) blob centres in pixels (origin top-left, y down) in one encoded image."""
    from wandcal.calib.detect import detect_blobs

    return detect_blobs(decode_image(data, camera), config).uv


def detect_frameset(images: dict[str, bytes], cameras: dict[str, Camera],
                    config: DetectConfig | None = None) -> dict[str, np.ndarray]:
    """Blob centres per camera id of one synchronised frame set, detected in parallel with the
    settings' ``[detect]`` group (``config``; None: the detector's defaults)."""
    futures = {cid: _executor().submit(detect_one, data, cameras[cid], config) for cid, data in images.items()}
    return {cid: f.result() for cid, f in futures.items()}


def detect_static(images: dict[str, list[bytes]], cameras: dict[str, Camera],
                  config: DetectConfig | None = None) -> dict[str, np.ndarray]:
    """Static-object marker positions per camera, averaged over each camera's images."""
    from wandcal.calib.detect import static_markers_from_frames

    out = {}
    for cid, datas in images.items():
        frames = list(_executor().map(lambda d, c=cameras[cid]: detect_one(d, c, config), datas))
        out[cid] = static_markers_from_frames(frames)
    return out


def static_observations(markers: dict[str, np.ndarray], rig: Rig) -> StaticObservations:
    """:class:`StaticObservations` from the ``(K, 2)`` marker positions per camera id of :func:`detect_static`."""
    index = {c.id: i for i, c in enumerate(rig.cameras)}
    cams = np.concatenate([np.full(len(uv), index[c], dtype=np.int64) for c, uv in markers.items()])
    return StaticObservations(camera=cams, uv=np.concatenate(list(markers.values())))
