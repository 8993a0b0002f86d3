"""Whole-building queries: the memory-mapped sidecar, the spatial exclusion index and the
log-confidence that keeps near-certain cells apart, each against an independent reference
(scipy's logsumexp in float64, brute-force distances, the parquet table itself)."""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from scipy.special import logsumexp

from care_maps.core.errors import StoreError
from care_maps.core.store import TEXT_SCHEMA, open_writer, write_table_atomic
from care_maps.fuse.measures import candidate_columns, candidate_metadata
from care_maps.fuse.sidecar import SidecarWriter, sidecar_path
from care_maps.query import load_map
from care_maps.query.confidence import log_confidence
from care_maps.query.map import map_from_table
from care_maps.replan.attempts import ReplanConfig, available_after, next_goal

VOCAB = ["chair", "sofa", "table", "bed", "lamp"]
CELL = 0.05


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _write_grid(tmp_path, nx: int = 40, ny: int = 30, d: int = 16, chunk: int = 300):
    """A grid map written chunk by chunk as the fusion does: cells.parquet and its sidecar."""
    rng = np.random.default_rng(3)
    text = _unit(rng.normal(size=(len(VOCAB), d))).astype(np.float32)
    ix, iy = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    keep = rng.random(ix.size) < 0.8  # holes, as a real floor has
    ix, iy = ix.ravel()[keep], iy.ravel()[keep]
    n = ix.size
    feats = _unit(rng.normal(size=(n, d)) * 0.3 + text[rng.integers(0, len(VOCAB), n)])
    feats[:3] = text[1]  # three near-certain sofas: their confidences tie at 1.0 in float32
    feats[1] = _unit(text[1] + 1e-3 * text[2])  # ...not quite the same
    md = {
        **candidate_metadata(VOCAB, 100.0, "test"),
        b"care.grid.cell_size": repr(CELL).encode(),
        b"care.schema_version": b"1",
    }
    path = tmp_path / "cells.parquet"
    sidecar = SidecarWriter(sidecar_path(path), n, d, len(VOCAB), len(VOCAB), md)
    writer = None
    for lo in range(0, n, chunk):
        rows = slice(lo, min(lo + chunk, n))
        m = rows.stop - lo
        table = candidate_columns(
            feats[rows], text, 100.0, num_views=np.full(m, 3), stderr=rng.random(m),
            pwkl=rng.random(m), first_id=lo, with_log_confidence=True,
        )  # fmt: skip
        sidecar.write(table)
        table = table.drop_columns(["log_confidence"])
        for name, values in (
            ("x", (ix[rows] + 0.5) * CELL), ("y", (iy[rows] + 0.5) * CELL), ("z_max", np.ones(m))
        ):  # fmt: skip
            table = table.append_column(name, pa.array(values.astype(np.float32)))
        if writer is None:
            writer = open_writer(path, table.schema.with_metadata(md))
        writer.write_table(table.replace_schema_metadata(md))
    writer.close()
    sidecar.commit()
    text_table = pa.table({"name": VOCAB, "embedding": list(text)}, schema=TEXT_SCHEMA)
    write_table_atomic(text_table, tmp_path / "text.parquet")
    return path, text


def test_sidecar_map_equals_the_table_and_scipy(tmp_path) -> None:
    path, text = _write_grid(tmp_path)
    cmap = load_map(tmp_path, "grid")
    assert cmap.log_confidence_rows is not None  # memory-mapped, not decoded
    assert isinstance(cmap.features, np.memmap)
    full = map_from_table(pq.read_table(path), text, "grid")  # the parquet table, decoded
    np.testing.assert_array_equal(np.asarray(cmap.features, np.float32), full.features)
    np.testing.assert_array_equal(cmap.top_classes, full.top_classes)
    np.testing.assert_array_equal(cmap.positions, full.positions)
    # log P_c[y] against scipy in float64 from the stored (float16) features
    logits = 100.0 * full.features.astype(np.float64) @ text.T.astype(np.float64)
    reference = logits - logsumexp(logits, axis=1, keepdims=True)
    got = log_confidence(cmap, np.arange(len(VOCAB)))
    np.testing.assert_allclose(got.T, reference, rtol=1e-5, atol=1e-6)
    # near-certain cells: the precise form tells them apart where exp() in float32 cannot
    exact = -np.log1p(np.exp(logits[:3] - logits[:3, 1:2]).sum(1) - 1.0)  # P_c[sofa] of 0..2
    assert np.all(np.float32(np.exp(exact)) == 1.0)  # all three read 1.0 as float32 P
    assert got[1, 1] < got[1, 0]  # cell 1 is less sure than cell 0 ...
    assert np.all(got[1, :3] < 0)  # ...and none is rounded up to certainty


def test_a_sidecar_of_another_map_is_refused_not_ignored(tmp_path) -> None:
    path, _ = _write_grid(tmp_path)
    index = sidecar_path(path) / "index.json"
    meta = json.loads(index.read_text())
    meta["fingerprint"] = "another map"
    index.write_text(json.dumps(meta))
    with pytest.raises(StoreError, match=r"cells\.query: the query cache of another map"):
        load_map(tmp_path, "grid")


@pytest.mark.parametrize("radius", [0.0, 0.05, 0.3, 1.0])
def test_spatial_exclusion_equals_brute_force(tmp_path, radius: float) -> None:
    _write_grid(tmp_path)
    cmap = load_map(tmp_path, "grid")
    rng = np.random.default_rng(0)
    xy = cmap.positions[:, :2]
    for c in rng.integers(0, cmap.num_candidates, 20):
        brute = np.flatnonzero(((xy - xy[c]) ** 2).sum(-1) <= radius**2)
        np.testing.assert_array_equal(cmap.near(int(c), radius), brute)


def test_replan_after_failures_matches_the_pass_over_every_cell(tmp_path) -> None:
    """next_goal with the spatial index picks what the all-cells exclusion gives."""
    _write_grid(tmp_path)
    cmap = load_map(tmp_path, "grid")
    conf = log_confidence(cmap, [2])
    visited: list[int] = []
    for _ in range(10):
        choice = next_goal(cmap, "table", visited, config=ReplanConfig(strategy="min_stderr", k=4))
        available = np.ones((1, cmap.num_candidates), bool)
        for v in visited:
            available = available_after(available, np.array([v]), cmap.positions, 1.0)
        if visited:
            from care_maps.replan.strategies import STRATEGIES, Situation, candidate_set

            cset = candidate_set("confidence", conf, available, 4)
            columns = {"stderr": cmap.stderr, "entropy": cmap.entropy, "pwkl": cmap.pwkl}
            pick = STRATEGIES["min_stderr"].rule(Situation(conf, available, cset, columns))
            want = int(pick.candidate[0])
        else:
            want = int(np.argmax(np.where(available, conf, -np.inf)))
        assert choice.candidate == want
        if choice.candidate < 0:
            break
        visited.append(choice.candidate)
    assert len(visited) >= 3


def test_first_attempt_prefers_the_surest_of_near_certain_cells(tmp_path) -> None:
    _write_grid(tmp_path)
    cmap = load_map(tmp_path, "grid")
    choice = next_goal(cmap, "sofa")
    ranked = np.argsort(-log_confidence(cmap, [1])[0], kind="stable")
    assert choice.candidate == ranked[0]
    assert choice.confidence == pytest.approx(1.0)
