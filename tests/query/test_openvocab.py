"""Free text joining the vocabulary: confidence and class ranks against scipy's softmax over
the vocabulary plus the query, and a brute-force stable ranking."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import softmax

from care_maps.core.errors import QueryError
from care_maps.query.map import NOT_IN_TOP, CandidateMap
from care_maps.query.openvocab import QueryTarget, open_query
from care_maps.query.store_text import NoTextSideError
from care_maps.query.text import TextMatch

N, D, NCLS = 300, 12, 7


def _unit(x: np.ndarray) -> np.ndarray:
    return (x / np.linalg.norm(x, axis=-1, keepdims=True)).astype(np.float32)


def _map(top_width: int, scale: float = 5.0) -> CandidateMap:
    rng = np.random.default_rng(4)
    text, feats = _unit(rng.normal(size=(NCLS, D))), _unit(rng.normal(size=(N, D)))
    logits = scale * feats.astype(np.float64) @ text.T
    order = np.argsort(-logits, axis=1, kind="stable")[:, :top_width].astype(np.int16)
    lse = np.log(np.exp(logits).sum(1))
    zeros = np.zeros(N, np.float32)
    return CandidateMap(
        kind="instances", vocabulary=tuple(f"c{i}" for i in range(NCLS)), text=text,
        logit_scale=scale, features=feats, log_norm=lse.astype(np.float32), top_classes=order,
        entropy=zeros, stderr=zeros, pwkl=zeros, num_views=np.ones(N, np.int32),
        positions=np.zeros((N, 3), np.float32),
    )  # fmt: skip


@pytest.mark.parametrize("width", [NCLS, 3])
def test_joined_query_is_one_more_softmax_class(width: int) -> None:
    cmap = _map(width)
    query = _unit(np.random.default_rng(9).normal(size=D))
    match = TextMatch("a red mug", (NCLS,), ("a red mug",), (1.0,), "joins the vocabulary")
    target = QueryTarget.of_text(cmap, match, 3.0 * query)  # any scale: normalised
    all_text = np.vstack([cmap.text, query]).astype(np.float64)
    probs = softmax(cmap.logit_scale * cmap.features.astype(np.float64) @ all_text.T, axis=1)
    np.testing.assert_allclose(target.confidence(), probs[:, -1], rtol=2e-5, atol=1e-7)
    # ranks: the query's place in each candidate's descending class order (before ties)
    brute = np.argsort(-probs, axis=1, kind="stable")
    want = np.argmax(brute == NCLS, axis=1)
    for limit in (None, 2, width + 1):
        depth = width + 1 if limit is None else min(limit, width + 1)
        expect = np.where(want < depth, want, NOT_IN_TOP)
        np.testing.assert_array_equal(target.class_rank(limit), expect)
    assert target.free_text


def test_vocabulary_class_is_itself_and_lookup_gaps_fall_back() -> None:
    cmap = _map(NCLS)
    same = open_query(cmap, "C3", embed=lambda texts: pytest.fail("no embedding"))
    assert (same.match.class_id, same.match.method, same.free_text) == (3, "vocabulary", False)
    np.testing.assert_array_equal(same.class_rank(), cmap.class_rank(np.array([3]))[0])

    def lacks(texts):
        raise NoTextSideError("not in the text table")

    fallback = open_query(cmap, "sofa", embed=lacks)
    assert fallback.match.method.startswith("sentence")
    assert not fallback.free_text

    def broken(texts):
        raise QueryError("weights moved; pass --weights DIR")

    with pytest.raises(QueryError, match="--weights"):
        open_query(cmap, "sofa", embed=broken)
    with pytest.raises(QueryError, match="dimension"):
        QueryTarget.of_text(cmap, fallback.match, np.ones(D + 1, np.float32))
