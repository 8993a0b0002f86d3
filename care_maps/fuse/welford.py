"""The per-channel half of Chan's merge, in place on the state's rows (numba).

:class:`care_maps.fuse.accumulate.CandidateSums` keeps each candidate's weighted mean ``mu`` and sum of
squared deviations ``M2`` of its d feature channels in one row ``[mu | M2]``. Merging a
view's samples as array expressions gathers the rows it touches into a copy, updates the
copy and scatters it back: at d = 512 that is 4 KB read and written twice per sample, more
memory traffic than arithmetic. The loop here updates the rows where they are.

Each update is ``M2 += delta * (delta * c_m2)`` and ``mu += delta * c_mu`` with
``delta = f - mu``, each a fused multiply-add (one rounding), as torch's ``addcmul_``
computes it on CPUs with FMA: the state is the same bits as that form's, and does not
depend on which instructions the machine has (LLVM's ``fma`` is exact everywhere).
"""

from __future__ import annotations

import numpy as np
from numba import types
from numba.core.extending import intrinsic

from care_maps.runtime.jit import kernel

__all__ = ["merge_moments"]


@intrinsic
def _fma(typingctx, a, b, c):
    """``a * b + c`` rounded once (LLVM's ``llvm.fma``)."""
    if not (isinstance(a, types.Float) and a == b == c):
        return None

    def codegen(context, builder, signature, args):
        return builder.fma(*args)

    return a(a, b, c), codegen


@kernel
def _merge(moments, ids, features, seen, c_mu, c_m2):
    d = features.shape[1]
    for i in range(ids.size):
        row = moments[ids[i]]
        f = features[i]
        if not seen[i]:  # a candidate's first sample is its mean; M2 stays 0
            for j in range(d):
                row[j] = f[j]
            continue
        a = c_m2[i]
        b = c_mu[i]
        for j in range(d):
            delta = f[j] - row[j]
            row[d + j] = _fma(delta, delta * a, row[d + j])
            row[j] = _fma(delta, b, row[j])


def merge_moments(
    moments: np.ndarray,
    ids: np.ndarray,
    features: np.ndarray,
    seen: np.ndarray,
    c_mu: np.ndarray,
    c_m2: np.ndarray,
) -> None:
    """Merge one sample into each of the distinct candidates ``ids`` (k,), in place.

    Args:
        moments: (capacity, 2 d) ``[mu | M2]`` rows, float32 or float64.
        features: (k, d) the samples, in ``moments``' precision.
        seen: (k,) bool, whether the candidate has a sample already (else it is written).
        c_mu, c_m2: (k,) ``w / W_new`` and ``w W_old / W_new``, in ``moments``' precision.
    """
    _merge(moments, ids, features, seen, c_mu, c_m2)
