"""The rig of the cameras a recording opens: a rig.json given beside them, the simulated scene's own
rig, a replay folder's rig.json, or the intrinsics the drivers bring (``wandcal capture`` and the
service's live capture both start from it)."""

from __future__ import annotations

from pathlib import Path

from wandcal.calib.rig import Rig
from wandcal.drivers.camera import CameraDriver
from wandcal.drivers.errors import DriverError

DEFAULT_WAND_LENGTH_M = 0.5


def camera_rig(cameras: list[CameraDriver], rig_file: Path | None = None, wand_length: float | None = None) -> Rig:
    """``rig_file`` when given, else the simulated scene's rig, a replay folder's rig.json (when no
    ``wand_length`` overrides it), or the drivers' own intrinsics with ``wand_length`` (metres;
    default :data:`DEFAULT_WAND_LENGTH_M`). A camera without intrinsics raises :class:`DriverError`."""
    from wandcal.capture.folder import read_rig

    if rig_file:
        return read_rig_file(rig_file)
    scene = simulated_scene(cameras)
    if scene is not None:
        return scene.rig
    intrinsics = [c.intrinsics for c in cameras]
    missing = [c.camera_id for c, k in zip(cameras, intrinsics) if k is None]
    if missing:
        raise DriverError(f"no intrinsics for camera(s) {', '.join(missing)}; give --rig rig.json "
                          "(docs/capture-format.md) with every camera's K and dist")
    folders: set[Path] = {f for c in cameras if (f := getattr(c, "folder", None)) is not None}
    if len(folders) == 1 and wand_length is None:
        return read_rig(next(iter(folders)))
    return Rig(cameras=tuple(k for k in intrinsics if k is not None), wand_length=wand_length or DEFAULT_WAND_LENGTH_M)


def simulated_scene(cameras: list[CameraDriver]):
    """The simulated scene when every camera comes from the same one (one sim:// URL), else None."""
    scenes = {id(c.scene): c.scene for c in cameras if hasattr(c, "scene")}
    if len(scenes) == 1 and len(cameras) == len(next(iter(scenes.values())).rig.cameras):
        return next(iter(scenes.values()))
    return None


def read_rig_file(path: Path) -> Rig:
    """A rig.json file; one that cannot be read or parsed raises, naming it."""
    from wandcal.capture.rig_file import load_json, rig_from_json

    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DriverError(f"{path}: cannot read the rig ({exc})") from None
    return rig_from_json(load_json(data, str(path)), str(path))
