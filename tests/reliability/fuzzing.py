"""Hypothesis strategies for bad user files, and the one check every reader must pass.

A reader given bad input may accept it or refuse it with a :class:`CalibrationError` (or its
subclass ``CaptureFormatError``) whose message names the file; any other exception is a
traceback for the user, and fails the test. Every input tried is counted by kind, and the
counts are printed at the end of the run (``conftest.py``) for docs/reliability.md.
"""

from __future__ import annotations

import codecs
import collections
import json
import os
import random
import re

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

from wandcal.calib.errors import CalibrationError

TRIED: collections.Counter = collections.Counter()  # kind of bad input -> inputs tried this run

# Deterministic (derandomize) so CI never fails on a new random draw; database=None so a run
# leaves nothing behind. Examples per reader: enough to reach every branch of a reader's checks
# (each refusal is a few lines of parsing), small enough for ~2 minutes of these tests in all.
# A longer run (docs/reliability.md): WANDCAL_FUZZ_SCALE=50 multiplies every count below.
SCALE = max(int(os.environ.get("WANDCAL_FUZZ_SCALE", "1") or 1), 1)
FUZZ = settings(max_examples=60 * SCALE, deadline=None, derandomize=True, database=None,
                suppress_health_check=list(HealthCheck))
FUZZ_SLOW = settings(FUZZ, max_examples=20 * SCALE)  # readers whose accepted inputs run a calibration
FUZZ_PIPELINE = settings(FUZZ, max_examples=8 * SCALE)  # a whole calibration per example (~0.3 s)

# Cells a person or a broken tool writes: huge and negative numbers, overflow, not-a-number,
# other number syntaxes and scripts, quoting, control and bidi characters, JSON words.
NASTY_CELLS = (
    "99999999999999999999", "9" * 400, "-99999999999999999999", "1e400", "-1e400", "1e-400", "-1", "-0", "0",
    "nan", "NaN", "inf", "-inf", "Infinity", "", " ", "0x1F", "1_000", "١٢٣", "½", "+5", "5.", ".5", "--1", "1e",
    '"', '"unterminated', "'", "cam1\x00", "\u202ecam1", "𝟙", "null", "[]", "{}", "true", "\t", "\r", "1,2",
    "ｃａｍ１", "CAM1", " cam1 ", "\ufeffframe", "7" * 140_000,  # past the csv module's field limit
)
# JSON values that break a reader which trusts a field's type or size.
NASTY_JSON = (
    None, True, False, 0, -1, -(10**30), 10**30, 1e308, -1e308, 1e-320, "", "x", "1", [], {}, [[]], [None], [1],
    [[1, 2], [3]], {"a": 1}, "NaN", [float("nan")], [float("inf")], list(range(100)), "ｃａｍ１",
)
ENCODINGS = ("utf-16", "utf-32", "latin-1", "cp1252", "shift_jis", "utf-8-sig")


def refused_cleanly(read, kind: str, names: str | tuple[str, ...] | None):
    """Call ``read()``; it may return, or raise CalibrationError naming one of ``names`` (a file
    name or field); anything else propagates and fails the test. Returns what ``read`` returned,
    or None when it refused."""
    TRIED[kind] += 1
    try:
        return read()
    except CalibrationError as exc:
        wanted = (names,) if isinstance(names, str) else names
        if wanted and not any(n in str(exc) for n in wanted):
            raise AssertionError(f"the message does not name {wanted}: {exc}") from exc
        return None


# -- bytes and text ----------------------------------------------------------------------------
def garbage_bytes(max_size: int = 3000):
    """Random bytes, often with a plausible start (a BOM, a header, a PNG or MATLAB signature)."""
    starts = st.sampled_from([b"", codecs.BOM_UTF8, codecs.BOM_UTF16_LE, b"frame,camera,u,v\n", b"{",
                              b"\x89PNG\r\n\x1a\n", b"MATLAB 5.0 MAT-file", b"\x00" * 8])
    return st.tuples(starts, st.binary(max_size=max_size)).map(lambda p: p[0] + p[1])


def wrong_encoding(text: str):
    """``text`` with a non-ASCII camera name, written in another encoding than UTF-8."""
    def encode(args):
        enc, accent = args
        bent = text.replace("cam1", accent, 1)
        return bent.encode(enc, errors="replace")
    return st.tuples(st.sampled_from(ENCODINGS), st.sampled_from(["cäm1", "カメラ1", "ĉam1", "cam1€"])).map(encode)


def truncated(data: bytes):
    """``data`` cut at a random byte (a crash mid-write, a partial download)."""
    return st.integers(0, max(len(data) - 1, 0)).map(lambda k: data[:k])


# -- CSV tables ------------------------------------------------------------------------------
def mutated_csv(text: str):
    """A valid CSV ``text`` with 1-4 mutations: nasty cells, missing, extra and duplicated
    columns, a missing header, garbage lines, truncation, other line ends and BOMs."""
    return st.tuples(st.integers(1, 4), st.randoms(use_true_random=False)).map(lambda a: _mutate_csv(text, *a))


def _mutate_csv(text: str, count: int, rnd: random.Random) -> bytes:
    lines = text.splitlines()
    for _ in range(count):
        op = rnd.randrange(10)
        if op <= 2 and len(lines) > 1:  # a nasty cell
            k = rnd.randrange(1, len(lines))
            cells = lines[k].split(",")
            cells[rnd.randrange(len(cells))] = rnd.choice(NASTY_CELLS)
            lines[k] = ",".join(cells)
        elif op == 3:  # a column missing
            j = rnd.randrange(len(lines[0].split(",")))
            lines = [",".join(c for i, c in enumerate(line.split(",")) if i != j) for line in lines]
        elif op == 4:  # an extra column, in the header or not
            lines = [line + "," + (rnd.choice(("extra", "u", "frame")) if i == 0 else rnd.choice(NASTY_CELLS))
                     for i, line in enumerate(lines) if rnd.random() < 0.95 or i == 0]
        elif op == 5 and lines:  # no header / a header only
            lines = lines[1:] if rnd.random() < 0.5 else lines[:1]
        elif op == 6:  # a garbage line
            junk = "".join(rnd.choice(",;\"'\t x0123456789.-e\x7f\u00e9") for _ in range(rnd.randrange(40)))
            lines.insert(rnd.randrange(len(lines) + 1), junk)
        elif op == 7:  # rows that are too short or too long
            if len(lines) > 1:
                k = rnd.randrange(1, len(lines))
                lines[k] = ",".join(lines[k].split(",")[: rnd.randrange(4)]) if rnd.random() < 0.5 else lines[k] * 3
        elif op == 8:  # many rows of one nasty value
            lines += [",".join([rnd.choice(NASTY_CELLS)] * 4)] * rnd.randrange(1, 50)
        else:  # line ends
            sep = rnd.choice(("\r\n", "\r", "\n\n"))
            return _finish(sep.join(lines), rnd)
    return _finish("\n".join(lines) + "\n", rnd)


def _finish(text: str, rnd: random.Random) -> bytes:
    data = text.encode("utf-8", errors="surrogatepass")
    if rnd.random() < 0.1:
        data = codecs.BOM_UTF8 + data
    if rnd.random() < 0.15:
        data = data[: rnd.randrange(len(data) + 1)]
    return data


# -- other text formats (TOML, YAML, XML) ---------------------------------------------------
NUMBER = re.compile(r"-?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?")


def mutated_text(text: str):
    """A valid text file (TOML, YAML, XML) with 1-4 line-level mutations: a number replaced by a
    nasty cell, a line deleted, doubled or moved, a garbage line, other line ends, truncation."""
    return st.tuples(st.integers(1, 4), st.randoms(use_true_random=False)).map(lambda a: _mutate_text(text, *a))


def _mutate_text(text: str, count: int, rnd: random.Random) -> bytes:
    lines = text.splitlines()
    for _ in range(count):
        op = rnd.randrange(8)
        k = rnd.randrange(len(lines)) if lines else 0
        if op <= 3 and lines:  # a number (or, without one, a word) replaced
            found = list(NUMBER.finditer(lines[k])) or list(re.finditer(r"\w+", lines[k]))
            if found:
                m = rnd.choice(found)
                lines[k] = lines[k][: m.start()] + rnd.choice(NASTY_CELLS) + lines[k][m.end():]
        elif op == 4 and lines:
            del lines[k]
        elif op == 5 and lines:
            lines.insert(rnd.randrange(len(lines) + 1), lines[k])
        elif op == 6:
            junk = "".join(rnd.choice("[]{}<>=:,\"' x0123456789.-e\t\u00e9") for _ in range(rnd.randrange(40)))
            lines.insert(rnd.randrange(len(lines) + 1), junk)
        else:
            return _finish(rnd.choice(("\r\n", "\r", "\n\n")).join(lines), rnd)
    return _finish("\n".join(lines) + "\n", rnd)


# -- JSON documents --------------------------------------------------------------------------
def mutated_json(doc: dict):
    """``doc`` as JSON text with 1-3 mutations: a node replaced by a value of the wrong type or
    size, a key removed or added, NaN and Infinity, numbers past float range, deep nesting,
    truncation."""
    return st.tuples(st.integers(1, 3), st.randoms(use_true_random=False)).map(lambda a: _mutate_json(doc, *a))


def _mutate_json(doc: dict, count: int, rnd: random.Random) -> bytes:
    doc = json.loads(json.dumps(doc))
    special = None
    for _ in range(count):
        op = rnd.randrange(9)
        parent, key = _random_node(doc, rnd)
        if parent is None:
            continue
        if op <= 2:
            parent[key] = rnd.choice(NASTY_JSON)
        elif op == 3 and isinstance(parent, dict):
            del parent[key]
        elif op == 4 and isinstance(parent, dict):
            parent[rnd.choice(("extra", "model", "id", "K", "format", "wand"))] = rnd.choice(NASTY_JSON)
        elif op in (5, 6):
            parent[key] = "@@SPECIAL@@"
            special = rnd.choice(("1" + "0" * 400, "-1" + "0" * 5000, "1e999", "NaN", "-Infinity",
                                  "[" * 5000 + "]" * 5000, "[" * 200000, '"\\ud800"', "0.1e-99999"))
        elif isinstance(parent, list) and parent:
            parent.append(parent[0])  # a list one too long
    text = json.dumps(doc, allow_nan=True)
    if special is not None:
        text = text.replace('"@@SPECIAL@@"', special)
    data = text.encode()
    if rnd.random() < 0.1:
        data = data[: rnd.randrange(len(data) + 1)]
    return data


def _random_node(doc, rnd: random.Random):
    """A random (container, key) inside ``doc``, walking down a random path."""
    parent, key = None, None
    node = doc
    for _ in range(rnd.randrange(1, 6)):
        if isinstance(node, dict) and node:
            parent, key = node, rnd.choice(list(node))
        elif isinstance(node, list) and node:
            parent, key = node, rnd.randrange(len(node))
        else:
            break
        node = parent[key]
    return parent, key
