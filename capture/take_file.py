"""A take folder (docs/capture-format.md, "Takes"): ``rig.json`` and ``take.csv``, every blob of an
ordinary recording with no labels; read with errors that name the file, line and column; written by
``wandcal simulate --take``. Also the updated result ``wandcal watch --write`` writes."""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wandcal.calib.rig import Rig
from wandcal.calib.watch.take import TakeBlobs, check_take
from wandcal.capture.csv_tables import decode_text
from wandcal.capture.folder import WAND_COLUMNS, CaptureFormatError, parse_wand_csv
from wandcal.capture.result_file import ResultFile
from wandcal.capture.rig_file import read_rig, rig_to_json
from wandcal.drivers.capture_files import RIG_FILE, TAKE_FILE

# A take is every blob of every frame: 12 cameras x 40 markers at 100 fps are ~1.2 MB a second, so a
# take file may be larger than a wand capture's (MAX_CSV_BYTES): 512 MB is about seven minutes of it.
MAX_TAKE_BYTES = 512 * 1024 * 1024
WATCH_FORMAT = "wandcal-watch/1"  # the record of what an updated result was derived from


@dataclass(frozen=True, eq=False)
class Take:
    """A take folder: its rig (cameras and intrinsics, as any capture's) and its blobs, sorted by frame."""

    rig: Rig
    blobs: TakeBlobs
    path: Path


def read_take(folder: str | Path) -> Take:
    """Read a take folder; refuses a missing or empty ``take.csv`` and blobs in fewer than three
    cameras, saying what to record instead."""
    folder = Path(folder)
    if not folder.is_dir():
        raise CaptureFormatError(f"{folder}: not a folder; give a take folder holding rig.json and {TAKE_FILE}")
    rig = read_rig(folder, allow_no_wand=True)
    path = folder / TAKE_FILE
    if not path.is_file():
        raise CaptureFormatError(f"{path}: not found; a take folder holds {TAKE_FILE} ({','.join(WAND_COLUMNS)}: every "
                                 "blob of every camera and frame, docs/capture-format.md)")
    size = path.stat().st_size
    if size > MAX_TAKE_BYTES:
        raise CaptureFormatError(f"{path}: {size} bytes, more than the {MAX_TAKE_BYTES} a take file may hold (about seven "
                                 "minutes of 12 cameras); split the take into shorter ones")
    obs = parse_wand_csv(decode_text(path.read_bytes(), str(path)), rig, str(path))
    order = np.argsort(obs.frame, kind="stable")
    blobs = TakeBlobs(obs.frame[order], obs.camera[order], obs.uv[order])
    check_take(rig, blobs, str(path))
    return Take(rig, blobs, folder)


def write_take(folder: str | Path, rig: Rig, blobs: TakeBlobs) -> None:
    """Write a take folder: rig.json and take.csv (pixels to 1e-4, as wand.csv)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / RIG_FILE).write_text(json.dumps(rig_to_json(rig), indent=2) + "\n")
    ids = rig.ids
    with open(folder / TAKE_FILE, "w") as fh:
        fh.write(",".join(WAND_COLUMNS) + "\n")
        fh.writelines(f"{f},{ids[c]},{uv[0]:.4f},{uv[1]:.4f}\n" for f, c, uv in zip(blobs.frame.tolist(), blobs.camera.tolist(), blobs.uv))


def updated_result(standing: ResultFile, take: Path, cameras: dict[str, dict]) -> dict:
    """The standing result's document with each camera of ``cameras`` (id -> {"R", "t", and figures:
    center_std_mm, rotation_std_deg, reprojection_rms_px, verdict, ...}) replaced, and a ``watch``
    record of what it was derived from: the take, the standing result (its path and SHA-256)."""
    doc = json.loads(json.dumps(standing.doc))
    for entry in doc["cameras"]:
        new = cameras.get(entry.get("id"))
        if new is None:
            continue
        R, t = np.asarray(new["R"]), np.asarray(new["t"])
        entry.update({key: value for key, value in new.items() if key not in ("R", "t")})
        entry["R"], entry["t"] = R.tolist(), t.tolist()
        entry["center"] = (-R.T @ t).tolist()
    doc["watch"] = {
        "format": WATCH_FORMAT,
        "take": str(take),
        "standing": str(standing.path),
        "standing_sha256": hashlib.sha256(standing.path.read_bytes()).hexdigest() if standing.path.is_file() else None,
        "resolved": sorted(cameras),
        "held": "the other cameras, the scale and the world frame are the standing result's",
    }
    return doc
