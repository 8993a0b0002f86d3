"""Counter-based random numbers: each draw is a hash of a seed and the ids it is for
(instance, class, view stamp), so a draw is the same in any batch, order or process."""

from __future__ import annotations

import numpy as np

__all__ = ["gaussian", "uniform"]

_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def _splitmix(x: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):
        z = x + _GOLDEN
        z = (z ^ (z >> np.uint64(30))) * _M1
        z = (z ^ (z >> np.uint64(27))) * _M2
        return z ^ (z >> np.uint64(31))


def _hash(seed: int, *parts: np.ndarray | np.integer | int) -> np.ndarray:
    h = _splitmix(np.asarray(np.uint64(seed & 0xFFFFFFFFFFFFFFFF)))
    for p in parts:
        h = _splitmix(h ^ np.asarray(p).astype(np.uint64))
    return h


def uniform(seed: int, *parts: np.ndarray | np.integer | int) -> np.ndarray:
    """Uniform [0, 1) numbers that depend only on ``seed`` and ``parts`` (counter-based)."""
    return (_hash(seed, *parts) >> np.uint64(11)).astype(np.float64) * 2.0**-53


def gaussian(seed: int, a: np.ndarray, b: np.ndarray, salt: int, dim: int) -> np.ndarray:
    """(N, dim) standard normal numbers from counters (Box-Muller)."""
    k = np.arange(dim, dtype=np.uint64)[None, :]
    u1 = uniform(seed, a[:, None], b[:, None], salt, k)
    u2 = uniform(seed, a[:, None], b[:, None], salt + 1000, k)
    return np.sqrt(-2.0 * np.log1p(-u1)) * np.cos(2.0 * np.pi * u2)
