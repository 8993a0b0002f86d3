"""Loading a hand-built map table and scoring it, against scipy's softmax and brute force."""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pytest
from scipy.special import softmax

from care_maps.core.errors import QueryError, StoreError
from care_maps.core.store import TEXT_SCHEMA, write_table_atomic
from care_maps.fuse.measures import candidate_columns, candidate_metadata
from care_maps.query import confidence, load_map, rank_by_confidence, resolve_text

VOCAB = ["chair", "sofa", "table", "bed", "lamp", "plant"]


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _write_store(
    tmp_path, kind: str, n_cand: int = 9, d: int = 8, seed: int = 0, scale: float = 30.0,
    sure: bool = False,
):  # fmt: skip
    rng = np.random.default_rng(seed)
    text = _unit(rng.normal(size=(len(VOCAB), d))).astype(np.float32)
    feats = _unit(rng.normal(size=(n_cand, d)))
    if sure:  # candidates that are exactly a class's text embedding
        feats[: len(VOCAB)] = text
    table = candidate_columns(
        feats, text, scale, num_views=np.arange(n_cand) % 4,
        stderr=rng.random(n_cand), pwkl=rng.random(n_cand),
    )  # fmt: skip
    if kind == "grid":
        table = table.append_column("x", pa.array(rng.random(n_cand).astype(np.float32)))
        table = table.append_column("y", pa.array(rng.random(n_cand).astype(np.float32)))
        table = table.append_column("z_max", pa.array(np.ones(n_cand, np.float32)))
        name = "cells"
    else:
        centres = rng.random((n_cand, 3)).astype(np.float32)
        table = table.append_column("center", pa.array(list(centres), pa.list_(pa.float32())))
        masks = [np.arange(i, i + 1 + i % 3, dtype=np.int32) for i in range(n_cand)]
        table = table.append_column("point_indices", pa.array(masks, pa.list_(pa.int32())))
        name = "instances"
    write_table_atomic(
        table, tmp_path / f"{name}.parquet", candidate_metadata(VOCAB, scale, "test")
    )
    # the store's text table lists the classes in another order: the loader must follow names
    order = np.array([3, 0, 5, 1, 2, 4])
    text_table = pa.table(
        {"name": [VOCAB[i] for i in order], "embedding": list(text[order])}, schema=TEXT_SCHEMA
    )
    write_table_atomic(text_table, tmp_path / "text.parquet")
    stored = np.asarray(table.column("feature").combine_chunks().flatten(), np.float64)
    return stored.reshape(n_cand, d), text


@pytest.mark.parametrize("kind", ["instances", "grid"])
def test_confidence_is_softmax_of_stored_features(tmp_path, kind) -> None:
    feats, text = _write_store(tmp_path, kind)
    cmap = load_map(tmp_path, kind)
    assert cmap.num_candidates == 9
    assert cmap.vocabulary == tuple(VOCAB)
    reference = softmax(30.0 * feats @ text.T.astype(np.float64), axis=1)  # (N, n)
    ys = np.array([2, 0, 2, 5, 1])
    np.testing.assert_allclose(confidence(cmap, ys), reference[:, ys].T, rtol=1e-4, atol=1e-7)
    ranking = rank_by_confidence(confidence(cmap, ys))
    np.testing.assert_array_equal(ranking[0], np.argsort(-reference[:, 2], kind="stable"))


def test_instance_masks_and_subset(tmp_path) -> None:
    _write_store(tmp_path, "instances")
    cmap = load_map(tmp_path, "instances")
    np.testing.assert_array_equal(cmap.mask(4), [4, 5])
    sub, ids = cmap.subset(np.array([False, True, False, False, False, True, False, False, True]))
    np.testing.assert_array_equal(ids, [1, 5, 8])
    np.testing.assert_array_equal(sub.mask(1), [5, 6, 7])
    np.testing.assert_array_equal(sub.mask(2), [8, 9, 10])
    np.testing.assert_allclose(confidence(sub, 3)[0], confidence(cmap, 3)[0, ids], rtol=1e-6)


def test_class_rank_matches_brute_force(tmp_path) -> None:
    _write_store(tmp_path, "instances")
    cmap = load_map(tmp_path, "instances")
    ys = np.array([0, 4, 4, 5])
    brute = np.array(
        [[list(cmap.top_classes[c]).index(y) for c in range(cmap.num_candidates)] for y in ys]
    )
    np.testing.assert_array_equal(cmap.class_rank(ys), brute)
    limited = cmap.class_rank(ys, limit=3)
    np.testing.assert_array_equal(limited, np.where(brute < 3, brute, np.iinfo(np.int16).max))


def test_missing_or_foreign_tables_are_one_clear_error(tmp_path) -> None:
    with pytest.raises(StoreError, match="no such table"):
        load_map(tmp_path, "grid")
    _write_store(tmp_path, "grid")
    with pytest.raises(QueryError, match="unknown map kind"):
        load_map(tmp_path, "voxels")  # type: ignore[arg-type]
    text = pa.table({"name": ["chair"], "embedding": [np.ones(8, np.float32)]}, schema=TEXT_SCHEMA)
    write_table_atomic(text, tmp_path / "text.parquet")
    with pytest.raises(QueryError, match="no text embedding for 5 classes"):
        load_map(tmp_path, "grid")


def test_text_resolution_reports_the_mapping(tmp_path) -> None:
    _write_store(tmp_path, "instances")
    cmap = load_map(tmp_path, "instances")
    exact = resolve_text(cmap, "  Sofa ")
    assert (exact.class_id, exact.method, exact.scores) == (1, "vocabulary", (1.0,))
    # an embedder in the map's own text space: "couch" embeds next to the stored "sofa" vector
    couch = cmap.text[1] + 0.05 * cmap.text[3]
    match = resolve_text(cmap, "couch", embed=lambda texts: np.stack([couch]), same_space=True)
    assert match.names[:2] == ("sofa", "bed")
    assert match.method == "map text"
    assert "'couch' -> sofa" in match.describe()
    with pytest.raises(QueryError, match="not a class"):
        cmap.class_id("couch")
    assert json.loads(json.dumps(match.scores))  # plain floats, reportable


def test_sentence_model_maps_free_text(tmp_path) -> None:
    sentence = pytest.importorskip("care_maps.core.encoders.sentence")
    if sentence.sentence_model().backend != "minilm":
        pytest.skip("all-MiniLM-L6-v2 is not installed (hashed fallback knows no synonyms)")
    _write_store(tmp_path, "instances")
    cmap = load_map(tmp_path, "instances")
    match = resolve_text(cmap, "couch")
    assert match.method == "sentence:minilm"
    assert match.names[0] == "sofa", match.describe()


@pytest.mark.parametrize("kind", ["instances", "grid"])
def test_confidence_of_a_sure_candidate_is_at_most_one(tmp_path, kind) -> None:
    """At CLIP's scale of 100, float32 rounding alone would read a sure candidate as 1.00002."""
    feats, text = _write_store(tmp_path, kind, d=16, scale=100.0, sure=True)
    conf = confidence(load_map(tmp_path, kind), np.arange(len(VOCAB)))
    reference = softmax(100.0 * feats @ text.T.astype(np.float64), axis=1).T
    assert conf.max() <= 1.0
    np.testing.assert_allclose(conf, reference, rtol=1e-3, atol=1e-6)


def test_list_values_are_flattens() -> None:
    """A list column's values are read without pyarrow's compute module, as ``flatten()``
    gives them: fixed-size and variable lists, sliced, empty."""
    from care_maps.query.map import _values

    for whole in (
        pa.array([[1, 2], [3, 4], [5, 6]], pa.list_(pa.float32(), 2)),
        pa.array([[1, 2], [3], [5, 6, 7]], pa.list_(pa.int32())),
        pa.array([[1, 2], [3], [5, 6, 7]], pa.large_list(pa.int32())),
        pa.array([[1, 2], None, [5]], pa.list_(pa.int32())),
    ):
        for col in (whole, whole.slice(1), whole.slice(1, 1), whole.slice(0, 0)):
            assert _values(col).equals(col.flatten())
