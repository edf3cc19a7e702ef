"""Memory policy for a command that computes once and exits (``wandcal calibrate`` and its kin).

A calibration allocates and frees arrays of tens to hundreds of megabytes many times over (each
linearisation, elimination and Schur complement). glibc hands every block above its mmap
threshold back to the kernel on ``free``, and NumPy asks the kernel for huge pages on large
arrays, so each new array is fresh memory that the kernel zeroes page by page: at 128 cameras x
3000 frames `--method lp` had the kernel clearing ~6.8 GB of pages (``clear_page_erms``, 20% of
the process's samples under ``perf``) for a peak of 1.2 GB. A process that exits when it is done
gains nothing from returning memory early. It keeps what it frees instead: glibc serves every
block from its heap and never trims it, and NumPy does not ask for huge pages (a huge page is
zeroed whole, 2 MB, on first touch of any part; with them the heap's reuse still left 2.3 s of
system time in that run). Measured in decision 0027.

Long-running commands (``serve``, ``capture``, ``guidance``) keep the defaults: they must give
memory back between jobs.
"""

from __future__ import annotations

import ctypes
import platform

# glibc's mallopt parameters (malloc.h)
M_TRIM_THRESHOLD = -1
M_MMAP_MAX = -4
NEVER_TRIM = 2**31 - 1  # bytes of free heap top kept before glibc trims it: the largest int it takes


def keep_freed_memory() -> bool:
    """Apply the policy to this process; True when glibc took it (elsewhere nothing changes)."""
    try:
        from numpy._core.multiarray import _set_madvise_hugepage  # type: ignore[attr-defined]  # private: NumPy's own switch (NUMPY_MADVISE_HUGEPAGE)

        _set_madvise_hugepage(False)
    except ImportError:  # another NumPy layout: its default stays
        pass
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        libc = ctypes.CDLL(None)
        return bool(libc.mallopt(M_MMAP_MAX, 0)) and bool(libc.mallopt(M_TRIM_THRESHOLD, NEVER_TRIM))
    except (OSError, AttributeError):
        return False
