"""2D keypoints from DeepLabCut CSVs and aniposelib points arrays.

DeepLabCut's CSV (``save_as_csv``, or ``CollectedData_*.csv``): header rows ``scorer``, optional
``individuals`` (multi-animal), ``bodyparts`` and ``coords`` (``x``, ``y`` and, from a network,
``likelihood``), then one row per frame. The leading index columns are the frame number, or the
image path (``labeled-data/video/img0123.png``: the number in its file name is the frame). Pixels
are top-left, y down, as wandcal's. HDF5 (``.h5``) would need pandas and PyTables, which wandcal
does not depend on: save the CSV (``deeplabcut.analyze_videos(..., save_as_csv=True)``).

aniposelib's points array: ``(C, N, J, 2)`` (cameras, frames, joints, xy) or ``(C, N, 2)``, NaN
where unseen, the cameras in the TOML's order.
"""

from __future__ import annotations

import csv
import io
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wandcal.capture.csv_tables import MAX_FRAME
from wandcal.capture.folder import CaptureFormatError
from wandcal.capture.formats.cameras_in import check_size

# DeepLabCut's own default ``pcutoff`` (config.yaml): below it DeepLabCut's plots and videos hide
# a keypoint as not found
DEFAULT_MIN_LIKELIHOOD = 0.6
HEADER_ROWS = ("scorer", "individuals", "bodyparts", "coords")
INDIVIDUAL_SEPARATOR = "/"  # a multi-animal keypoint's name: individual/bodypart


@dataclass(frozen=True, eq=False)
class Keypoints:
    """One camera's keypoints: frame (K,) int; uv (K, 2) pixels, top-left, y down; label (K,) str,
    the keypoint's name; left_out, the camera-keypoint-frames not seen or below the threshold."""

    frame: np.ndarray
    uv: np.ndarray
    label: np.ndarray
    left_out: int
    source: str


def read_dlc_csv(path: Path, min_likelihood: float = DEFAULT_MIN_LIKELIHOOD) -> Keypoints:
    """One camera's keypoints from a DeepLabCut CSV (module docstring); errors name the file,
    the line and the column."""
    path = Path(path)
    if not 0 <= min_likelihood <= 1:
        raise CaptureFormatError(f"{path}: the likelihood threshold must lie between 0 and 1, got {min_likelihood}")
    if path.suffix.lower() in (".h5", ".hdf5"):
        raise CaptureFormatError(f"{path}: DeepLabCut's HDF5 needs pandas and PyTables, which wandcal does not use; "
                                 "save the keypoints as CSV (analyze_videos(..., save_as_csv=True)) and give that")
    check_size(path, "DeepLabCut CSV")
    try:
        rows = list(csv.reader(io.StringIO(path.read_text())))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise CaptureFormatError(f"{path}: cannot read a DeepLabCut CSV ({exc})") from None
    head, first, columns = _dlc_columns(rows, path)
    body = rows[max(head.values()) + 1:]
    frame: list[int] = []
    uv: list[list[float]] = []
    label: list[str] = []
    left_out = 0
    seen_frames: dict[int, int] = {}  # frame -> the line it was first on
    for k, row in enumerate(body):
        line = max(head.values()) + 2 + k
        if not any(c.strip() for c in row):
            continue
        f = _frame(row[:first], path, line)
        if f in seen_frames:
            raise CaptureFormatError(f"{path} line {line}: frame {f} again (first on line {seen_frames[f]}); give each "
                                     "frame once")
        seen_frames[f] = line
        for name, cols in columns.items():
            xy = [_cell(row, cols[c], path, line) for c in ("x", "y")]
            p = _cell(row, cols["likelihood"], path, line) if "likelihood" in cols else 1.0
            if not np.all(np.isfinite(xy)) or not p >= min_likelihood:
                left_out += 1
                continue
            frame.append(f)
            uv.append(xy)
            label.append(name)
    return Keypoints(np.array(frame, dtype=np.int64), np.array(uv, dtype=float).reshape(-1, 2),
                     np.array(label, dtype=str), left_out, str(path))


def _dlc_columns(rows: list[list[str]], path: Path) -> tuple[dict[str, int], int, dict[str, dict[str, int]]]:
    """A DeepLabCut CSV's header: (the row index of each of scorer/bodyparts/coords/individuals
    present; the first keypoint column; each keypoint's name -> {"x"|"y"|"likelihood": column})."""
    head = {}
    for k, row in enumerate(rows[:len(HEADER_ROWS)]):
        key = (row[0] if row else "").strip().lower()
        if key in HEADER_ROWS:
            head[key] = k
    if "bodyparts" not in head or "coords" not in head:
        raise CaptureFormatError(f"{path}: not a DeepLabCut CSV: the first rows must be scorer, bodyparts and coords "
                                 "(and individuals for multi-animal projects)")
    coords = [c.strip().lower() for c in rows[head["coords"]]]
    first = next((i for i, c in enumerate(coords) if c in ("x", "y", "likelihood")), None)
    if first is None:
        raise CaptureFormatError(f"{path} line {head['coords'] + 1}: the coords row has no x, y columns")
    parts = [c.strip() for c in rows[head["bodyparts"]]]
    who = [c.strip() for c in rows[head["individuals"]]] if "individuals" in head else None
    columns: dict[str, dict[str, int]] = {}
    for i in range(first, len(coords)):
        if coords[i] not in ("x", "y", "likelihood"):
            raise CaptureFormatError(f"{path} line {head['coords'] + 1}, column {i + 1}: coords {coords[i]!r} is not "
                                     "x, y or likelihood")
        name = parts[i] if i < len(parts) else ""
        if who is not None and i < len(who) and who[i] and who[i].lower() != "single":
            name = f"{who[i]}{INDIVIDUAL_SEPARATOR}{name}"
        columns.setdefault(name, {})[coords[i]] = i
    for name, cols in columns.items():
        if "x" not in cols or "y" not in cols or not name:
            raise CaptureFormatError(f"{path} line {head['bodyparts'] + 1}: keypoint {name!r} needs an x and a y column")
    return head, first, columns


def read_points_npy(path: Path, n_cams: int, toml: str) -> list[Keypoints]:
    """Every camera's keypoints from an aniposelib points array (module docstring); joint j is
    named ``joint<j>`` (a (C, N, 2) array has the one joint ``joint0``)."""
    check_size(path, "points array")
    try:
        arr = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise CaptureFormatError(f"{path}: not a NumPy .npy array ({exc}); give aniposelib's points array") from None
    if arr.ndim == 3:
        arr = arr[:, :, None, :]
    if arr.ndim != 4 or arr.shape[-1] != 2 or not np.issubdtype(arr.dtype, np.number):
        raise CaptureFormatError(f"{path}: shape {arr.shape}; aniposelib's points array is (cameras, frames, joints, 2) "
                                 "or (cameras, frames, 2) numbers")
    if arr.shape[0] != n_cams:
        raise CaptureFormatError(f"{path}: {arr.shape[0]} cameras (its first axis) but {toml} has {n_cams}; the "
                                 "array's cameras must be the TOML's, in its order")
    out = []
    for c in range(n_cams):
        seen = np.all(np.isfinite(arr[c]), axis=-1)  # (N, J)
        f, j = np.nonzero(seen)
        out.append(Keypoints(f.astype(np.int64), arr[c][f, j].astype(float), np.char.add("joint", j.astype(str)),
                             int((~seen).sum()), f"{path} camera {c}"))
    return out


def _frame(index: list[str], path: Path, line: int) -> int:
    """The frame number of a row's index cells: a whole number, or the number in an image's name."""
    cells = [c.strip() for c in index if c.strip()]
    if not cells:
        raise CaptureFormatError(f"{path} line {line}: no frame number or image name in the first column")
    if re.fullmatch(r"\d+", cells[0]):
        return _bounded(cells[0], path, line)
    found = re.search(r"(\d+)\D*$", Path(cells[-1]).name)
    if found is None:
        raise CaptureFormatError(f"{path} line {line}: {cells[-1]!r} is neither a frame number nor an image name with "
                                 "one; the first column must give the frame")
    return _bounded(found.group(1), path, line)


def _bounded(digits: str, path: Path, line: int) -> int:
    """A frame number within the capture format's range (before: 20 digits overflowed
    the frame array, 5,000 passed Python's digit limit, both as tracebacks)."""
    if len(digits) > len(str(MAX_FRAME)) or int(digits) > MAX_FRAME:
        raise CaptureFormatError(f"{path} line {line}: frame {digits[:30]}{'...' if len(digits) > 30 else ''} is out of "
                                 f"range; frame numbers are whole numbers from 0 to {MAX_FRAME}")
    return int(digits)


def _cell(row: list[str], i: int, path: Path, line: int) -> float:
    text = row[i].strip() if i < len(row) else ""
    if not text or text.lower() == "nan":
        return float("nan")
    try:
        return float(text)
    except ValueError:
        raise CaptureFormatError(f"{path} line {line}, column {i + 1}: {text!r} is not a number") from None
