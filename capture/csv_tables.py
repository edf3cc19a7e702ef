"""The CSV tables of a capture folder, cell by cell: the one decoder, the row readers whose errors
name the file, the line and the column, the fast column reader for well-formed files, and the writer.

The file formats themselves (which columns, which file) are capture/folder.py's.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from wandcal.calib.rig import Rig
from wandcal.capture.rig_file import CaptureFormatError

MAX_FRAME = 2**53  # frame numbers beyond this lose precision wherever they become floats (JSON, plots)
# The largest capture CSV read (wand.csv, static.csv, points.csv, axis.csv), checked before reading:
# the server's upload limit, ~2 million rows (8 cameras waving at 100 fps for 20 minutes, ten times
# a thorough wanding). Reading and calibrating take a bounded multiple of it (docs/reliability.md).
MAX_CSV_BYTES = 64 * 1024 * 1024


def frame_table(text: str, rig: Rig, columns: tuple[str, ...], source: str):
    """(frame (B,), camera (B,), uv (B, 2)) of a ``frame,camera,u,v`` table. Well-formed files
    (every capture wandcal writes) are converted column by column; anything else goes through
    the row-by-row reader, whose errors name the line and the column."""
    fast = _frame_table_fast(text, rig, columns)
    if fast is not None:
        return fast
    return frame_rows(csv_rows(text, columns, source), rig, source)


def frame_rows(rows: list[tuple[int, dict]], rig: Rig, source: str):
    """(frame (B,), camera (B,), uv (B, 2)) of parsed ``frame,camera,u,v`` rows, row by row."""
    frame = np.empty(len(rows), dtype=np.int64)
    camera = np.empty(len(rows), dtype=np.int64)
    uv = np.empty((len(rows), 2))
    lookup = {cid: i for i, cid in enumerate(rig.ids)}
    for k, (line, row) in enumerate(rows):
        frame[k] = int_cell(row["frame"], f"{source} line {line}, column 'frame'")
        camera[k] = camera_cell(row["camera"], lookup, rig, f"{source} line {line}")
        where = f"{source} line {line} (frame {frame[k]})"
        uv[k] = float_cell(row["u"], f"{where}, column 'u'"), float_cell(row["v"], f"{where}, column 'v'")
    return frame, camera, uv


def _frame_table_fast(text: str, rig: Rig, columns: tuple[str, ...]):
    """The table parsed by numpy's C reader, or None when any cell would need a message."""
    if "\0" in text or '"' in text:
        return None
    first, _, rest = text.partition("\n")
    header = [h.strip() for h in first.split(",")]
    if any(c not in header for c in columns) or len(set(header)) != len(header):
        return None
    frame_c, cam_c, u_c, v_c = (header.index(c) for c in columns)
    # an empty table makes loadtxt warn; it is checked here instead of turning warnings into
    # errors, whose filter is process-wide and not thread-safe (the server reads in many threads)
    if not rest.strip():
        return None
    # from bytes, not io.StringIO: a StringIO holds its text as 4 bytes a character, which made
    # reading a 64 MB wand.csv peak at 8 times its size (bench/bench_memory.py)
    # the rows after the header, so no skiprows: NumPy notes (warns) how a skipped count meets a blank
    # line, and silencing that would change the process-wide warnings filter, which is not thread-safe
    raw = rest.encode()
    # one pass over the text, not one for the numbers and one for the camera ids (0.29 -> 0.22 s at 64
    # cameras x 3000 frames); a cell longer than the longest id is cut to one character more than
    # it, which matches no id and sends the table to the row-by-row reader
    width = max(map(len, rig.ids), default=0) + 1
    dtype = np.dtype([("frame", "f8"), ("camera", f"U{width}"), ("u", "f8"), ("v", "f8")])
    try:
        table = np.loadtxt(io.BytesIO(raw), delimiter=",", usecols=(frame_c, cam_c, u_c, v_c), dtype=dtype, ndmin=1,
                           encoding="utf-8")
    except ValueError:
        return None
    del raw
    if len(table) == 0:
        return None
    frame, uv, cams = table["frame"], np.stack([table["u"], table["v"]], axis=1), table["camera"]
    if not (np.all(np.isfinite(frame)) and np.all(np.isfinite(uv)) and np.all(frame == np.round(frame)) and frame.min() >= 0 and frame.max() <= MAX_FRAME):
        return None
    # each distinct cell stripped on its own (str.strip, as np.char.strip does), not the column: the
    # same camera per row, without importing numpy.char (a `wandcal check` imported it for this alone)
    cells, index = np.unique(cams, return_inverse=True)
    lookup = {cid: i for i, cid in enumerate(rig.ids)}
    ids = [str(cell).strip() for cell in cells]
    if any(cid not in lookup for cid in ids):
        return None
    return frame.astype(np.int64), np.array([lookup[cid] for cid in ids], dtype=np.int64)[index], uv


def csv_records(data: bytes) -> list[bytes]:
    """The records of a CSV file as wandcal writes them (every writer: :func:`write_capture`, the
    stream's appends, the recorder): each ends in ``\n`` (``\r\n`` from the csv module), and no
    cell holds a line end, as camera ids cannot (wandcal.calib.rig.CAMERA_ID). A last piece
    without its ``\n`` was cut by a crash and is not a record. Crash recovery counts with this."""
    pieces = data.split(b"\n")
    return [p + b"\n" for p in pieces[:-1]]


def write_csv(path: Path, columns: tuple[str, ...], rows) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        w.writerows(rows)


def read_csv_text(path: Path) -> str:
    size = path.stat().st_size
    if size > MAX_CSV_BYTES:
        raise CaptureFormatError(f"{path}: {size} bytes, more than the {MAX_CSV_BYTES} a capture file may hold "
                                 "(about 2 million rows); split the recording into shorter captures, or keep every "
                                 "n-th frame")
    return decode_text(path.read_bytes(), str(path))


def decode_text(data: bytes, source: str) -> str:
    """A CSV file's bytes as text: UTF-8, with or without a byte-order mark (spreadsheets write
    one). The one decoder of every capture CSV, read from a folder (the CLI, replay) or uploaded."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise CaptureFormatError(f"{source}: not a text file (it does not decode as UTF-8); give a CSV file") from None


def csv_rows(text: str, columns: tuple[str, ...], source: str) -> list[tuple[int, dict]]:
    if "\0" in text:
        raise CaptureFormatError(f"{source}: holds binary data (NUL bytes), not CSV text; the header must be "
                                 f"{','.join(columns)}")
    if not text.strip():  # not a bad header: no header at all (a recording that never started, a failed copy)
        raise CaptureFormatError(f"{source}: the file is empty; it needs the header {','.join(columns)} and a row a "
                                 "blob (record or detect the capture again, or copy the file again)")
    # newline="": the csv module itself finds each record's end, as it does when writing; str.splitlines
    # would also split at \x1c-\x1e, \x85 and \u2028, inside a cell
    reader = csv.DictReader(io.StringIO(text, newline=""))
    try:
        return _dict_rows(reader, columns, source)
    except csv.Error as exc:  # a field past the csv module's size limit, a quote left open
        raise CaptureFormatError(f"{source} line {reader.line_num}: not CSV ({exc}); the header must be "
                                 f"{','.join(columns)}") from None


def _dict_rows(reader: csv.DictReader, columns: tuple[str, ...], source: str) -> list[tuple[int, dict]]:
    header = [h.strip() for h in (reader.fieldnames or [])]
    missing = [c for c in columns if c not in header]
    if missing:
        raise CaptureFormatError(
            f"{source}: missing column(s) {', '.join(missing)}; the header must be {','.join(columns)}"
        )
    reader.fieldnames = header
    out = []
    for line, row in enumerate(reader, start=2):
        if not any((v or "").strip() for v in row.values() if isinstance(v, str)):
            continue
        out.append((line, row))
    return out


def camera_cell(value: str | None, lookup: dict[str, int], rig: Rig, where: str) -> int:
    key = (value or "").strip()
    if key not in lookup:
        raise CaptureFormatError(f"{where}: unknown camera id {key!r}; rig.json lists {', '.join(rig.ids)}: if "
                                 "rig.json is of another capture, put the rig.json of the cameras that recorded this "
                                 f"one beside it, else add {key!r} to rig.json")
    return lookup[key]


def float_cell(value: str | None, where: str) -> float:
    try:
        x = float((value or "").strip())
    except ValueError:
        raise CaptureFormatError(f"{where}: {value!r} is not a number") from None
    if not math.isfinite(x):
        raise CaptureFormatError(f"{where}: {value!r} is not finite; drop rows of undetected blobs instead of NaN")
    return x


def int_cell(value: str | None, where: str) -> int:
    try:
        number = int((value or "").strip())
    except ValueError:
        raise CaptureFormatError(f"{where}: {value!r} is not a whole frame number") from None
    if not 0 <= number <= MAX_FRAME:
        raise CaptureFormatError(f"{where}: frame {value!r} is out of range; frame numbers are whole numbers from 0 "
                                 f"to {MAX_FRAME}")
    return number
