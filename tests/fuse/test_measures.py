"""The measures against independent references: scipy, statsmodels and hand-worked values."""

from __future__ import annotations

import math

import numpy as np
import pyarrow as pa
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import rel_entr, softmax
from scipy.stats import entropy as scipy_entropy
from statsmodels.stats.weightstats import DescrStatsW

from care_maps.fuse.accumulate import CandidateSums
from care_maps.fuse.measures import (
    candidate_columns,
    class_distribution,
    entropy,
    log_norm,
    pwkl_linear,
    pwkl_pairwise,
    pwkl_terms,
    top_classes,
    weighted_stderr,
)


def _unit(rng: np.random.Generator, *shape: int) -> np.ndarray:
    x = rng.normal(size=shape)
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _sums(P_views: list[np.ndarray]) -> tuple[np.ndarray, ...]:
    terms = [pwkl_terms(P) for P in P_views]
    S = np.stack([t[0].sum(0) for t in terms])
    Q = np.stack([t[1].sum(0) for t in terms])
    A = np.stack([t[2].sum(0) for t in terms])
    return S, Q, A, np.array([len(P) for P in P_views])


def _kl_reference(P: np.ndarray) -> float:
    """Mean pairwise symmetric KL with scipy's rel_entr, the clamp of docs/method.md applied."""
    P = np.clip(P, 1e-12, None)
    m = len(P)
    total = 0.0
    for j in range(m):
        for k in range(j + 1, m):
            total += 0.5 * (rel_entr(P[j], P[k]).sum() + rel_entr(P[k], P[j]).sum())
    return total * 2 / (m * (m - 1))


def test_class_distribution_is_scipy_softmax() -> None:
    rng = np.random.default_rng(0)
    f, t = _unit(rng, 7, 16), _unit(rng, 5, 16)
    P = class_distribution(f, t, scale=100.0)
    np.testing.assert_allclose(P, softmax(100.0 * f @ t.T, axis=1), rtol=1e-12)
    np.testing.assert_allclose(P.sum(1), 1.0)
    # confidence of any class from log_norm alone
    np.testing.assert_allclose(
        np.exp(10.0 * f @ t.T - log_norm(f, t, 10.0)[:, None]), class_distribution(f, t, 10.0)
    )


def test_entropy_matches_scipy() -> None:
    rng = np.random.default_rng(1)
    P = rng.dirichlet(np.full(9, 0.3), size=20)
    P[0] = np.eye(9)[3]  # a one-hot row: 0 log 0 = 0
    np.testing.assert_allclose(entropy(P), scipy_entropy(P, axis=1), rtol=1e-12, atol=1e-15)


def test_pairwise_matches_rel_entr() -> None:
    rng = np.random.default_rng(2)
    P_views = [rng.dirichlet(np.full(6, 0.5), size=m) for m in (2, 3, 7)]
    P_views[1][0] = np.eye(6)[0]  # zeros: the 1e-12 clamp matters
    ref = np.array([_kl_reference(P) for P in P_views])
    np.testing.assert_allclose(pwkl_pairwise(P_views), ref, rtol=1e-10)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    sizes=st.lists(st.integers(2, 12), min_size=1, max_size=5),
    n=st.integers(1, 30),
    concentration=st.sampled_from([0.05, 0.5, 5.0]),
)
def test_linear_equals_pairwise(seed: int, sizes: list[int], n: int, concentration: float) -> None:
    rng = np.random.default_rng(seed)
    P_views = [rng.dirichlet(np.full(n, concentration), size=m) for m in sizes]
    S, Q, A, m = _sums(P_views)
    lin, pair = pwkl_linear(S, Q, A, m), pwkl_pairwise(P_views)
    np.testing.assert_allclose(lin, pair, rtol=1e-6, atol=1e-9 * max(1.0, np.abs(pair).max()))


def test_pwkl_infinite_below_two_views() -> None:
    rng = np.random.default_rng(3)
    P_views = [
        rng.dirichlet(np.ones(4), size=1),
        np.zeros((0, 4)),
        rng.dirichlet(np.ones(4), size=2),
    ]
    S, Q, A, m = _sums(P_views)
    lin = pwkl_linear(S, Q, A, m)
    assert np.isinf(lin[0])
    assert np.isinf(lin[1])
    assert np.isfinite(lin[2])
    assert np.isinf(pwkl_pairwise(P_views)[:2]).all()
    # identical views: zero divergence, never a tiny negative
    same = np.repeat(rng.dirichlet(np.ones(4), size=1), 3, axis=0)
    assert pwkl_linear(*_sums([same])) == pytest.approx(0.0, abs=1e-12)
    assert pwkl_linear(*_sums([same]))[0] >= 0


def _stream(W: list[np.ndarray], F: list[np.ndarray]) -> np.ndarray:
    W1 = np.array([w.sum() for w in W])
    W2 = np.array([(w * w).sum() for w in W])
    swf = np.stack([(w[:, None] * f).sum(0) for w, f in zip(W, F, strict=True)])
    swf2 = np.stack([(w[:, None] * f * f).sum(0) for w, f in zip(W, F, strict=True)])
    return weighted_stderr(W1, W2, swf, swf2, np.array([len(w) for w in W]))


def test_weighted_stderr_hand_worked() -> None:
    # f1 = (1, 0), w1 = 1; f2 = (0, 1), w2 = 3. mu = (1/4, 3/4); both channel variances
    # (1 * 0.75^2 + 3 * 0.25^2) / 4 = 3/16; m_eff = 16 / 10; SE = sqrt(3/16 / 1.6).
    se = _stream([np.array([1.0, 3.0])], [np.array([[1.0, 0.0], [0.0, 1.0]])])
    assert se[0] == pytest.approx(math.sqrt(0.1875 / 1.6), rel=1e-12)
    assert se[0] == pytest.approx(0.34232659844, rel=1e-9)


def test_weighted_stderr_matches_statsmodels() -> None:
    rng = np.random.default_rng(4)
    W = [rng.uniform(0.1, 2.0, m) for m in (2, 5, 40)]
    F = [_unit(rng, m, 24) for m in (2, 5, 40)]
    ours = _stream(W, F)
    for i, (w, f) in enumerate(zip(W, F, strict=True)):
        stats = DescrStatsW(f, weights=w, ddof=0)
        m_eff = w.sum() ** 2 / (w * w).sum()
        assert ours[i] == pytest.approx(stats.std.mean() / math.sqrt(m_eff), rel=1e-9)
    # unit weights: the plain form, population std over sqrt(m)
    f = F[1]
    plain = _stream([np.ones(5)], [f])[0]
    assert plain == pytest.approx(f.std(axis=0).mean() / math.sqrt(5), rel=1e-9)


def test_weighted_stderr_infinite_and_clamped() -> None:
    f = np.array([[0.6, 0.8]])
    assert np.isinf(_stream([np.array([2.0])], [f])[0])
    assert np.isinf(
        weighted_stderr(np.zeros(1), np.zeros(1), np.zeros((1, 2)), np.zeros((1, 2)), np.zeros(1))
    )[0]
    # identical views: variance rounds to a hair below zero; clamped, not NaN
    same = np.repeat(np.array([[0.1, 0.3, 0.7]]), 3, axis=0)
    se = _stream([np.array([0.3, 0.3, 0.3])], [same])[0]
    assert se >= 0
    assert se < 1e-7


def test_top_classes_order_and_ties() -> None:
    P = np.array([[0.1, 0.4, 0.1, 0.4]])
    classes, probs = top_classes(P, limit=3)
    assert classes.tolist() == [[1, 3, 0]]
    assert classes.dtype == np.int16
    np.testing.assert_allclose(probs, [[0.4, 0.4, 0.1]])


def test_candidate_columns_contract() -> None:
    rng = np.random.default_rng(5)
    fused, text = 3.0 * _unit(rng, 4, 8), _unit(rng, 120, 8)
    table = candidate_columns(
        fused, text, 50.0, num_views=np.array([1, 2, 3, 4]), stderr=np.ones(4), pwkl=np.ones(4)
    )
    assert table.schema.field("feature").type == pa.list_(pa.float16())
    assert table.schema.field("top_classes").type == pa.list_(pa.int16())
    assert table.schema.field("top_probs").type == pa.list_(pa.float16())
    assert table.schema.field("candidate_id").type == pa.int32()
    for name in ("log_norm", "entropy", "stderr", "pwkl"):
        assert table.schema.field(name).type == pa.float32()
    feat = np.array(table.column("feature").to_pylist(), dtype=np.float64)
    np.testing.assert_allclose(np.linalg.norm(feat, axis=1), 1.0, atol=2e-3)
    # P_c from the stored feature and log_norm sums to one and agrees with top_probs
    P = np.exp(50.0 * feat @ text.T - table.column("log_norm").to_numpy()[:, None])
    np.testing.assert_allclose(P.sum(1), 1.0, rtol=1e-5)
    top = np.array(table.column("top_classes").to_pylist())
    assert top.shape == (4, 100)
    np.testing.assert_array_equal(top[:, 0], P.argmax(1))
    probs = np.array(table.column("top_probs").to_pylist(), dtype=np.float64)
    np.testing.assert_allclose(probs, np.take_along_axis(P, top, 1), rtol=2e-3, atol=1e-6)
    np.testing.assert_allclose(
        table.column("entropy").to_numpy(), scipy_entropy(P, axis=1), rtol=1e-4
    )


@pytest.mark.parametrize(("dtype", "rel"), [(np.float64, 1e-9), (np.float32, 1e-5)])
def test_candidate_sums_stream_equals_batch(dtype: type, rel: float) -> None:
    rng = np.random.default_rng(6)
    ids = rng.integers(0, 30, 400)
    w = rng.uniform(0.1, 1.0, 400)
    f = _unit(rng, 400, 12)
    text = _unit(rng, 7, 12)
    sums = CandidateSums(12, text, 20.0, capacity=2, dtype=dtype)  # forces growth
    for chunk in np.array_split(np.arange(400), 9):  # repeated ids within a call
        sums.add(ids[chunk], w[chunk], f[chunk])
    assert sums.size == ids.max() + 1
    for c in (0, 7, 29):
        sel = ids == c
        P = class_distribution(f[sel], text, 20.0)
        assert sums.pwkl()[c] == pytest.approx(pwkl_pairwise([P])[0], rel=1e-6)
        stats = DescrStatsW(f[sel], weights=w[sel], ddof=0)
        m_eff = w[sel].sum() ** 2 / (w[sel] ** 2).sum()
        assert sums.stderr()[c] == pytest.approx(stats.std.mean() / math.sqrt(m_eff), rel=rel)
        np.testing.assert_allclose(sums.fused()[c], stats.mean, rtol=rel * 10, atol=rel / 10)
        assert sums.num_views[c] == sel.sum()


def test_float32_state_exact_where_views_agree() -> None:
    """Views agreeing to 1e-4: the float32 Welford/Chan state matches float64 references
    (statsmodels' weighted std, the paper's pairwise pwKL) where float32 sums of w f and
    w f^2 would have lost every digit of the spread."""
    rng = np.random.default_rng(11)
    d, n, m, n_cand = 512, 100, 12, 40
    text = _unit(rng, n, d)
    base = _unit(rng, n_cand, d)
    f = base[:, None, :] + 1e-4 * rng.normal(size=(n_cand, m, d)) / math.sqrt(d)
    f /= np.linalg.norm(f, axis=2, keepdims=True)
    w = rng.uniform(0.2, 1.0, (n_cand, m))
    sums = CandidateSums(d, text, 100.0)
    for j in range(m):  # one view at a time, as the grid streams them
        sums.add(np.arange(n_cand), w[:, j], f[:, j].astype(np.float32))
    f32 = f.astype(np.float32).astype(np.float64)  # the samples as the state saw them
    for c in range(n_cand):
        stats = DescrStatsW(f32[c], weights=w[c], ddof=0)
        m_eff = w[c].sum() ** 2 / (w[c] ** 2).sum()
        expected = stats.std.mean() / math.sqrt(m_eff)
        assert sums.stderr()[c] == pytest.approx(expected, rel=1e-3)
        P = class_distribution(f32[c], text, 100.0)
        assert sums.pwkl()[c] == pytest.approx(pwkl_pairwise([P])[0], rel=1e-3)
    # the streaming sums of docs/method.md in float32 cancel to noise on the same data
    wf = np.einsum("cj,cjd->cd", w, f32).astype(np.float32)
    wf2 = np.einsum("cj,cjd->cd", w, f32 * f32).astype(np.float32)
    naive = weighted_stderr(w.sum(1), (w * w).sum(1), wf, wf2, np.full(n_cand, m))
    assert np.max(np.abs(naive / sums.stderr() - 1)) > 0.1


@pytest.mark.parametrize("limit", [50, 10**12, 10**17])
def test_candidate_sums_reserved_or_grown_give_the_same_state(limit: int) -> None:
    """A limit reserves the state at once (10**12 and 10**17 rows are refused: it grows
    instead); the state is the same as grown from a small capacity."""
    rng = np.random.default_rng(8)
    text = _unit(rng, 7, 16)
    grown = CandidateSums(16, text, 30.0, capacity=2)
    reserved = CandidateSums(16, text, 30.0, limit=limit)
    for _ in range(6):
        ids = rng.choice(50, 20, replace=False)
        w, f = rng.uniform(0.1, 1.0, 20), _unit(rng, 20, 16).astype(np.float32)
        grown.add(ids, w, f)
        reserved.add(ids, w, f)
    assert reserved.size == grown.size
    for a, b in zip(grown._tables, reserved._tables, strict=True):
        np.testing.assert_array_equal(a[: grown.size], b[: grown.size])


def test_candidate_sums_state_size() -> None:
    """At most ~6 KB of streaming state per cell at d = 512, n = 100 (the memory target)."""
    assert CandidateSums.bytes_per_candidate(512, 100) <= 6 * 1024
    sums = CandidateSums(512, np.eye(100, 512), 100.0, capacity=1000)
    assert sums.nbytes == 1000 * CandidateSums.bytes_per_candidate(512, 100)
