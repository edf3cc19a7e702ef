"""OpenCV ``FileStorage`` YAML parsed in Python, with bounded work and messages naming the line.

``cv2.FileStorage``'s C++ parser writes past a heap block on some damaged files (a truncated
``!!opencv-matrix`` and, read after it, a matrix without ``cols`` and ``dt``); glibc then aborts
the whole process, a server with it. So files from users are read here instead, never by OpenCV.

The subset read is what OpenCV and :func:`wandcal.capture.formats.anipose_opencv.to_opencv_yaml`
write: a ``%YAML:1.0`` / ``%YAML 1.2`` header and ``---``, block maps and block sequences by
indentation (``-`` alone on its line or ``- key: value``), plain, single- and double-quoted
scalars, ``# comments``, flow ``[ ... ]`` and ``{ ... }`` that may wrap over lines, and maps tagged
``!!opencv-matrix`` (``rows``, ``cols``, ``dt``, ``data``), returned as NumPy arrays.
Anchors, aliases, block scalars (``|``, ``>``) and other tags are refused.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np

from wandcal.calib.errors import CalibrationError

MAX_TEXT_CHARS = 4_000_000  # a 256-camera calibration is ~400 kB; ten times that is no calibration
MAX_MATRIX_ELEMENTS = 10_000  # wandcal's largest matrix is 3x3 and OpenCV's longest lens 1x14
MAX_DEPTH = 16  # the deepest file wandcal writes nests 4 levels (cameras, item, matrix, data)
MATRIX_TAG = "!!opencv-matrix"
# OpenCV's one-letter depths (persistence.cpp symbolToType); all are read as float64.
MATRIX_DTYPES = frozenset("ucwsifdh")
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
_SPECIAL = {".nan": float("nan"), ".inf": float("inf"), "+.inf": float("inf"), "-.inf": float("-inf")}
_ESCAPES = {"n": "\n", "t": "\t", "r": "\r", "0": "\0", '"': '"', "\\": "\\", "/": "/", "'": "'"}


def parse_number(token: str) -> float:
    """A plain scalar as a float: decimal syntax only (Python's ``float`` would take ``1_000``,
    ``nan`` or Arabic digits), and OpenCV's ``.nan`` / ``.inf``; raises ValueError otherwise."""
    s = token.strip()
    if _NUMBER.fullmatch(s):
        return float(s)
    if s.lower() in _SPECIAL:
        return _SPECIAL[s.lower()]
    raise ValueError(f"{token!r} is not a number")


class _Parser:
    """Recursive descent over (line number, indent, content) triples; flow values char by char."""

    def __init__(self, text: str, source: str):
        self.source = source
        self.lines = _logical_lines(text, source)
        self.k = 0

    def fail(self, line: int, what: str) -> CalibrationError:
        return CalibrationError(f"{self.source}: line {line}: {what}; docs/formats.md, opencv-yaml")

    def block(self, indent: int, depth: int, path: str = ""):
        if depth > MAX_DEPTH:
            raise self.fail(self.lines[self.k][0], f"nested deeper than {MAX_DEPTH} levels")
        content = self.lines[self.k][2]
        if content == "-" or content.startswith("- "):
            return self.sequence(indent, depth, path)
        return self.mapping(indent, depth, path)

    def sequence(self, indent: int, depth: int, path: str) -> list:
        items: list = []
        while self.k < len(self.lines) and self.lines[self.k][1] == indent and _is_item(self.lines[self.k][2]):
            line, _, content = self.lines[self.k]
            rest = content[1:].lstrip()
            if not rest:
                self.k += 1
                items.append(self.nested(indent, depth, f"{path}[{len(items)}]"))
            elif _key_split(rest) is not None:  # "- key: value": a map indented at the key
                self.lines[self.k] = (line, indent + len(content) - len(rest), rest)
                items.append(self.block(self.lines[self.k][1], depth + 1, f"{path}[{len(items)}]"))
            else:
                self.k += 1
                items.append(self.flow_whole(rest, line, depth))
        return items

    def mapping(self, indent: int, depth: int, path: str) -> dict:
        out: dict = {}
        while self.k < len(self.lines) and self.lines[self.k][1] == indent and not _is_item(self.lines[self.k][2]):
            line, _, content = self.lines[self.k]
            split = _key_split(content)
            if split is None:
                raise self.fail(line, f"expected 'key: value', found {content[:40]!r}")
            key, rest = split
            if key in out:
                raise self.fail(line, f"{key!r} is given twice")
            self.k += 1
            tagged = rest.startswith(MATRIX_TAG)
            if tagged:
                rest = rest[len(MATRIX_TAG):].strip()
            elif rest.startswith(("!", "&", "*", "|", ">")):
                raise self.fail(line, f"{key!r}: tags, anchors, aliases and block scalars are not read ({rest[:20]!r})")
            if rest:
                value = self.flow_whole(rest, line, depth)
            elif self.k < len(self.lines) and self.lines[self.k][1] == indent and _is_item(self.lines[self.k][2]):
                value = self.sequence(indent, depth + 1, _join(path, key))  # "key:" then "- item" at the key's indent
            else:
                value = self.nested(indent, depth, _join(path, key))
            out[key] = _matrix(value, _join(path, key), line, self) if tagged else value
        if self.k < len(self.lines) and self.lines[self.k][1] > indent:
            raise self.fail(self.lines[self.k][0], "indented deeper than the line before allows")
        return out

    def nested(self, indent: int, depth: int, path: str):
        """The block under a line that ends in ``:`` or ``-``; an empty value when nothing is."""
        if self.k < len(self.lines) and self.lines[self.k][1] > indent:
            return self.block(self.lines[self.k][1], depth + 1, path)
        return ""

    def flow_whole(self, text: str, line: int, depth: int):
        value, end = _Flow(text, line, self, depth).value(0)
        if text[end:].strip():
            raise self.fail(line, f"unexpected {text[end:].strip()[:20]!r} after a value")
        return value


class _Flow:
    """A flow value (scalar, ``[ ... ]``, ``{ ... }``) from one logical line."""

    def __init__(self, text: str, line: int, parser: _Parser, depth: int):
        self.s, self.line, self.p, self.depth = text, line, parser, depth

    def skip(self, i: int) -> int:
        while i < len(self.s) and self.s[i] in " \t":
            i += 1
        return i

    def value(self, i: int, depth: int = 0, stops: str = ""):
        if self.depth + depth > MAX_DEPTH:
            raise self.p.fail(self.line, f"nested deeper than {MAX_DEPTH} levels")
        i = self.skip(i)
        c = self.s[i:i + 1]
        if c == "[":
            return self.collection(i + 1, "]", depth)
        if c == "{":
            return self.collection(i + 1, "}", depth)
        if c in ('"', "'"):
            return self.quoted(i)
        j = i
        while j < len(self.s) and self.s[j] not in stops:
            j += 1
        return self.s[i:j].strip(), j

    def collection(self, i: int, close: str, depth: int):
        items: Any = [] if close == "]" else {}  # a list for "]", a dict for "}"
        i = self.skip(i)
        if self.s[i:i + 1] == close:
            return items, i + 1
        while True:
            if close == "}":
                split = _key_split(self.s[i:], flow=True)
                if split is None:
                    raise self.p.fail(self.line, "expected 'key: value' in { ... }")
                key, _ = split
                i = self.s.index(":", i) + 1
                if key in items:
                    raise self.p.fail(self.line, f"{key!r} is given twice")
                items[key], i = self.value(i, depth + 1, ",}")
            else:
                item, i = self.value(i, depth + 1, ",]")
                items.append(item)
            i = self.skip(i)
            c = self.s[i:i + 1]
            if c == close:
                return items, i + 1
            if c != ",":
                raise self.p.fail(self.line, f"'{close}' missing (the {'list' if close == ']' else 'map'} is not closed)")
            i += 1

    def quoted(self, i: int):
        q, out, j = self.s[i], [], i + 1
        while j < len(self.s):
            c = self.s[j]
            if c == q:
                if q == "'" and self.s[j + 1:j + 2] == "'":  # '' is a quote inside '...'
                    out.append("'")
                    j += 2
                    continue
                return "".join(out), j + 1
            if c == "\\" and q == '"' and j + 1 < len(self.s):
                out.append(_ESCAPES.get(self.s[j + 1], self.s[j + 1]))
                j += 2
                continue
            out.append(c)
            j += 1
        raise self.p.fail(self.line, "a quoted string is not closed")


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def _is_item(content: str) -> bool:
    return content == "-" or content.startswith("- ")


def _key_split(content: str, flow: bool = False) -> tuple[str, str] | None:
    """``key: rest`` -> (key, rest); None when ``content`` is no key (a ':' must end or be followed by a space)."""
    m = re.match(r'\s*("(?:[^"\\]|\\.)*"|\'[^\']*\'|[^\s:"\'\[\]{},#][^:]*?)\s*:(?:\s|$)', content)
    if m is None or (flow and re.match(r"\s*[\[{]", content)):
        return None
    key = m.group(1)
    if key[0] in "\"'":
        key = key[1:-1]
    return key, content[m.end():].strip()


def _strip_comment(line: str) -> str:
    """``line`` without a ``#`` comment (one at the start or after a space, outside quotes)."""
    quote = None
    for j, c in enumerate(line):
        if quote:
            if c == quote:
                quote = None
        elif c in "\"'" and (j == 0 or line[j - 1] in " \t[{,:-"):
            quote = c
        elif c == "#" and (j == 0 or line[j - 1] in " \t"):
            return line[:j]
    return line


def _logical_lines(text: str, source: str) -> list[tuple[int, int, str]]:
    """(1-based line number, indent, content) for each non-blank line after the header; a flow
    ``[`` or ``{`` left open continues onto the next lines, which are joined to it."""
    out: list[tuple[int, int, str]] = []
    pending: tuple[int, int, str] | None = None
    for n, raw in enumerate(text.splitlines(), 1):
        body = _strip_comment(raw).rstrip()
        if "\t" in body[: len(body) - len(body.lstrip())]:
            raise CalibrationError(f"{source}: line {n}: indented with a tab; YAML indents with spaces")
        if pending is not None:
            pending = (pending[0], pending[1], pending[2] + " " + body.strip())
        elif not body.strip() or (not out and (body.startswith("%YAML") or body.strip() == "---")):
            continue
        elif body.strip() in ("---", "..."):
            raise CalibrationError(f"{source}: line {n}: a second YAML document; give one calibration per file")
        else:
            pending = (n, len(body) - len(body.lstrip(" ")), body.strip())
        if _flow_balance(pending[2]) <= 0:
            out.append(pending)
            pending = None
    if pending is not None:
        raise CalibrationError(f"{source}: line {pending[0]}: a '[' or '{{' is never closed (a cut-off file?)")
    return out


def _flow_balance(content: str) -> int:
    """Open ``[``/``{`` minus closed, outside quotes (a cut-off flow list stays positive)."""
    depth, quote = 0, None
    for c in content:
        if quote:
            quote = None if c == quote else quote
        elif c in "\"'":
            quote = c
        elif c in "[{":
            depth += 1
        elif c in "]}":
            depth -= 1
    return depth


def _matrix(value, path: str, line: int, parser: _Parser) -> np.ndarray:
    """An ``!!opencv-matrix`` map as a (rows, cols) float64 array, checked against its own sizes."""
    where = path
    if not isinstance(value, dict):
        raise parser.fail(line, f"{where} must be a map of rows, cols, dt and data")
    for field in ("rows", "cols", "dt", "data"):
        if field not in value:
            raise parser.fail(line, f"{where} has no {field!r}")
    try:
        rows, cols = (parse_number(value[f]) if isinstance(value[f], str) else -1.0 for f in ("rows", "cols"))
    except ValueError:
        rows = cols = -1.0
    if not (np.isfinite(rows) and np.isfinite(cols) and rows == int(rows) >= 0 and cols == int(cols) >= 0
            and rows * cols <= MAX_MATRIX_ELEMENTS):
        raise parser.fail(line, f"{where}: rows and cols must be whole numbers with rows x cols at most "
                          f"{MAX_MATRIX_ELEMENTS}, not {value['rows']!r} x {value['cols']!r}")
    if not isinstance(value["dt"], str) or value["dt"] not in MATRIX_DTYPES:
        raise parser.fail(line, f"{where}: dt must be one channel of {''.join(sorted(MATRIX_DTYPES))}, "
                          f"not {value['dt']!r}")
    data = value["data"]
    if not isinstance(data, list) or not all(isinstance(v, str) for v in data):
        raise parser.fail(line, f"{where}: data must be a list of numbers [ ... ]")
    if len(data) != rows * cols:
        raise parser.fail(line, f"{where}: data holds {len(data)} numbers, rows x cols = {int(rows * cols)}")
    try:
        return np.array([parse_number(v) for v in data], dtype=float).reshape(int(rows), int(cols))
    except ValueError as exc:
        raise parser.fail(line, f"{where}: {exc}") from None


def parse_opencv_yaml(text: str, source: str) -> dict:
    """The top-level map of an OpenCV YAML text: values are str (scalars, unconverted), list,
    dict, or float64 arrays of shape (rows, cols) for ``!!opencv-matrix`` maps.

    Raises :class:`CalibrationError` naming ``source`` and the line for anything outside the
    subset in the module docstring, for text past :data:`MAX_TEXT_CHARS` and for matrices past
    :data:`MAX_MATRIX_ELEMENTS`.
    """
    if len(text) > MAX_TEXT_CHARS:
        raise CalibrationError(f"{source}: {len(text)} characters, more than {MAX_TEXT_CHARS} that a calibration "
                               "file could hold; is it the right file?")
    text = text.removeprefix("\ufeff")
    parser = _Parser(text, source)
    if not parser.lines:
        raise CalibrationError(f"{source}: no YAML content; give the YAML 'wandcal export --format opencv-yaml' writes")
    first = parser.lines[0]
    doc = parser.block(first[1], 0)
    if parser.k < len(parser.lines):
        raise parser.fail(parser.lines[parser.k][0], "indented less than the first line, or a list after a map")
    if not isinstance(doc, dict):
        raise parser.fail(first[0], "the top level must be a map (unit, camera_count, cameras)")
    return doc
