"""keep_freed_memory: freed arrays' pages are reused instead of faulted in again."""

from __future__ import annotations

import subprocess
import sys

import pytest

_PROBE = """
import resource, sys
import numpy as np
if sys.argv[1] == "keep":
    from care_maps.runtime.malloc import keep_freed_memory
    assert keep_freed_memory()
np.ones(1 << 20).sum()  # warm up numpy's own buffers
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(10):  # a frame's temporaries: four 8 MiB arrays, touched, then freed
    arrays = [np.ones(1 << 20) for _ in range(4)]
    del arrays
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(mode: str) -> int:
    out = subprocess.run(
        [sys.executable, "-c", _PROBE, mode], capture_output=True, text=True, check=True
    )
    return int(out.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_freed_pages_are_reused() -> None:
    pages = 4 * (8 << 20) // 4096
    default, kept = _faults("default"), _faults("keep")
    assert kept <= pages  # the first round's pages serve every later round
    assert default > 4 * kept  # glibc's default hands them back, and they fault in again
