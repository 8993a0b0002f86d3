"""Kernels compile with or without a place to cache them."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numba
import numpy as np
import pytest

from care_maps.runtime.jit import kernel

SOURCE = """
def double_all(values):
    out = np.empty_like(values)
    for i in range(values.size):
        out[i] = 2 * values[i]
    return out
"""


def test_a_kernel_without_a_cache_location_still_compiles() -> None:
    # code with no source file: numba finds no cache location for it (the case of an
    # install whose directories cannot be written)
    scope: dict = {"np": np}
    exec(SOURCE, scope)
    with pytest.raises(RuntimeError, match="cannot cache"):
        numba.njit(cache=True)(scope["double_all"])
    double_all = kernel(scope["double_all"])
    np.testing.assert_array_equal(double_all(np.arange(4.0)), [0.0, 2.0, 4.0, 6.0])


MODULE = """
import numpy as np
from care_maps.runtime.jit import kernel


@kernel
def triple_all(values):
    out = np.empty_like(values)
    for i in range(values.size):
        out[i] = 3 * values[i]
    return out
"""

CALL = "import numpy as np, kern; print(kern.triple_all(np.arange(3.0)).tolist())"


@pytest.mark.slow
def test_a_damaged_cache_is_one_warning_and_the_kernel_still_runs(tmp_path) -> None:
    """A truncated cache index (a disk fault) is read by pickle and fails; the kernel says so
    once and compiles in memory. Each call is a fresh process, as a user's next command."""
    (tmp_path / "kern.py").write_text(MODULE)
    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(root)])}

    def run() -> subprocess.CompletedProcess:
        return subprocess.run(
            [sys.executable, "-c", CALL], env=env, capture_output=True, text=True, check=False
        )

    first = run()  # compiles and writes the cache
    assert first.returncode == 0, first.stderr
    assert first.stdout.strip() == "[0.0, 3.0, 6.0]"
    (index,) = (tmp_path / "__pycache__").glob("kern.triple_all-*.nbi")
    index.write_bytes(index.read_bytes()[:20])  # truncated
    damaged = run()
    assert damaged.returncode == 0, damaged.stderr
    assert damaged.stdout.strip() == "[0.0, 3.0, 6.0]"
    warnings = [line for line in damaged.stderr.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1
    assert "kern.triple_all" in warnings[0]
    assert "Traceback" not in damaged.stderr
