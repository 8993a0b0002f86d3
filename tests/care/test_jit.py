"""Kernels compile with or without a place to cache them."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from care.jit import kernel

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
