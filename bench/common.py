"""Shared helpers for the benchmark scripts: timing, camera-centre errors after alignment, and
writing a section of docs/benchmarks.md."""

from __future__ import annotations

import contextlib
import platform
import re
import sys
import time
from pathlib import Path

import numpy as np

from wandcal.calib.geometry import kabsch

DOC = Path(__file__).resolve().parents[1] / "docs" / "benchmarks.md"


def aligned_centres_mm(centres: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(N,) distances, mm, of ``centres`` (N, 3) from ``reference`` (N, 3), metres, after the best
    similarity map of the one onto the other (the gauge and scale a calibration may choose)."""
    Ra, ta, s = kabsch(centres, reference, scale=True)
    return np.linalg.norm(s * centres @ Ra.T + ta - reference, axis=1) * 1000


def aligned_rms_mm(centres: np.ndarray, reference: np.ndarray) -> float:
    """The RMS of :func:`aligned_centres_mm`: the rig's centre error against the truth, mm."""
    return float(np.sqrt(np.mean(np.square(aligned_centres_mm(centres, reference)))))


def timed(fn, *args, **kwargs):
    """(result, seconds) of one call."""
    start = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - start


@contextlib.contextmanager
def judge_timed(clock=time.process_time):
    """``with judge_timed() as (pipeline, inside):`` the run layer's module (``pipeline.calibrate``)
    with its judgement wrapped in place: each call's ``clock`` seconds (CPU by default: the machine
    is shared) are appended to the list ``inside``. The judgement is restored on leaving."""
    from wandcal.calib.run import calibrate as pipeline

    inside: list[float] = []
    judge = pipeline.judge

    def timed(*args, **kwargs):
        start = clock()
        try:
            return judge(*args, **kwargs)
        finally:
            inside.append(clock() - start)

    pipeline.judge = timed
    try:
        yield pipeline, inside
    finally:
        pipeline.judge = judge


def peak_rss_mb() -> float:
    """This process's peak resident set since it started or since :func:`reset_peak_rss`, MB (Linux)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def reset_peak_rss() -> None:
    """Start :func:`peak_rss_mb` again from the present resident set (Linux's clear_refs 5)."""
    with contextlib.suppress(OSError):
        Path("/proc/self/clear_refs").write_text("5")


def machine() -> str:
    import os

    import numpy
    import scipy

    from wandcal.calib.solve.backend.highs import new_highs

    highs = new_highs()  # without HiGHS's banner on the bench's stdout
    return (
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"NumPy {numpy.__version__}, SciPy {scipy.__version__}, HiGHS (highspy) {highs.version() if hasattr(highs, 'version') else '?'}"
    )


def replace_section(title: str, content: str) -> None:
    """Replace (or append) the section '## title' of docs/benchmarks.md with ``content``,
    keeping every other section as it is."""
    text = DOC.read_text() if DOC.exists() else "# Benchmarks\n\nEach section was written by the command it names, on the machine it names.\n"
    section = f"## {title}\n\n{content.strip()}\n"
    pattern = re.compile(rf"^## {re.escape(title)}\n.*?(?=^## |\Z)", re.S | re.M)
    text = pattern.sub(lambda _: section + "\n", text) if pattern.search(text) else text.rstrip() + "\n\n" + section
    DOC.write_text(text.rstrip() + "\n")


def write_section(title: str, body: str) -> None:
    """:func:`replace_section` with the command line, the machine and the date on top."""
    command = "python " + " ".join(sys.argv)
    replace_section(title, f"Command: `{command}`  \nMachine: {machine()}  \nDate: {time.strftime('%Y-%m-%d')}\n\n{body.strip()}")


def publish(title: str, text: str, write: bool, *, header: bool = True) -> int:
    """A bench's closing block: print ``text`` and, when ``write``, make it docs/benchmarks.md's
    section ``title`` (:func:`write_section`: the command, machine and date on top; with
    ``header=False``, :func:`replace_section`: ``text`` as it is). Returns 0, the script's exit status."""
    print(text)
    if write:
        (write_section if header else replace_section)(title, text)
    return 0
