"""The in-place Welford/Chan merge against hand-worked numbers and a float64 reference."""

from __future__ import annotations

import numpy as np

from care_maps.fuse.welford import merge_moments


def test_each_update_is_one_fused_multiply_add() -> None:
    # delta = 1 + 2^-12: delta * delta = 1 + 2^-11 + 2^-24 is a tie in float32 (rounds to
    # 1 + 2^-11), so M2 = -1 + delta^2 is 2^-11 rounded twice but 2^-11 + 2^-24 rounded once
    moments = np.array([[0.0, -1.0]], np.float32)
    merge_moments(
        moments,
        np.array([0]),
        np.array([[1 + 2**-12]], np.float32),
        np.array([True]),
        c_mu=np.array([0.5], np.float32),
        c_m2=np.array([1.0], np.float32),
    )
    assert moments[0, 1] == np.float32(2**-11 + 2**-24)
    assert moments[0, 0] == np.float32(0.5 + 2**-13)


def test_merge_follows_a_float64_reference_and_touches_only_its_rows() -> None:
    rng = np.random.default_rng(3)
    d, cap = 8, 6
    moments = np.zeros((cap, 2 * d), np.float32)
    moments[[1, 4]] = rng.normal(size=(2, 2 * d)).astype(np.float32) ** 2
    before = moments.copy()
    ids = np.array([4, 2, 1])
    feats = rng.normal(size=(3, d)).astype(np.float32)
    seen = np.array([True, False, True])
    c_mu = np.array([0.3, 1.0, 0.7], np.float32)
    c_m2 = np.array([2.1, 0.0, 0.4], np.float32)
    merge_moments(moments, ids, feats, seen, c_mu, c_m2)

    ref = before.astype(np.float64)
    for i, row in enumerate(ids):
        if not seen[i]:
            ref[row, :d] = feats[i]
            continue
        delta = feats[i] - ref[row, :d]
        ref[row, d:] += delta * delta * c_m2[i]
        ref[row, :d] += delta * c_mu[i]
    np.testing.assert_allclose(moments, ref, rtol=1e-6, atol=1e-7)
    untouched = [0, 3, 5]
    assert (moments[untouched] == before[untouched]).all()
    assert (moments[2, d:] == 0).all()  # a first sample: its mean, no spread
