"""The batch commands' memory policy (service/cli/support/batch_memory.py): freed memory serves the next array."""

import os
import platform
import subprocess
import sys

import pytest

# in a child process (the policy is process-wide): touch a 64 MB array, free it, touch another;
# print the minor page faults of each touch
PROBE = """
import resource, sys
import numpy as np
if sys.argv[1] == "policy":
    from wandcal.service.cli.support.batch_memory import keep_freed_memory
    assert keep_freed_memory()
def faults():
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt
out = []
for _ in range(2):
    before = faults()
    a = np.ones(8 << 20)  # 64 MB, written
    out.append(faults() - before)
    del a
print(*out)
"""
PAGES = (64 << 20) // 4096


def _faults(mode: str) -> list[int]:
    # 4 KB pages in both modes (the policy turns NumPy's huge pages off): faults count pages
    env = os.environ | {"NUMPY_MADVISE_HUGEPAGE": "0"}
    done = subprocess.run([sys.executable, "-c", PROBE, mode], check=True, capture_output=True, text=True, env=env)
    return [int(v) for v in done.stdout.split()]


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="a glibc policy")
def test_a_batch_process_reuses_what_it_frees_and_a_default_one_does_not():
    first, second = _faults("policy")
    assert first >= 0.5 * PAGES  # the first array is fresh memory: the kernel faults its pages in
    assert second <= 0.05 * PAGES  # the second reuses the first's pages: nothing to zero again
    _, default_second = _faults("default")
    assert default_second >= 0.5 * PAGES  # without the policy glibc returned them and they fault again
