"""Batch queries and replans without ground truth: every row equals repeated one-at-a-time
``next_goal`` calls (with the places already searched), free text resolves through the map's
own text side, and the same batch gives the same bytes."""

from __future__ import annotations

import io

import numpy as np
import pyarrow.parquet as pq
import pytest

from care_maps.core.encoders.sentence import sentence_model
from care_maps.core.errors import ReplanError
from care_maps.query.map import CandidateMap
from care_maps.replan import STRATEGIES
from care_maps.replan.attempts import ReplanConfig, next_goal
from care_maps.replan.batch import RANKING, BatchConfig, BatchQuery, plan_batch, read_queries

NAMES = ("chair", "sofa", "bed", "table", "lamp", "sink", "toilet", "tv", "plant", "cabinet")
N = 300


@pytest.fixture(scope="module")
def grid_map() -> CandidateMap:
    """A grid of N cells over 10 x 10 m whose features mix MiniLM class embeddings."""
    model = sentence_model()
    text = model.embed(list(NAMES)).astype(np.float32)
    rng = np.random.default_rng(5)
    mix = rng.dirichlet(np.full(len(NAMES), 0.3), size=N).astype(np.float32)
    feats = mix @ text + 0.05 * rng.normal(size=(N, text.shape[1])).astype(np.float32)
    feats /= np.linalg.norm(feats, axis=1, keepdims=True)
    scale = 20.0
    logits = scale * feats.astype(np.float64) @ text.T.astype(np.float64)
    m = logits.max(1, keepdims=True)
    log_norm = (m[:, 0] + np.log(np.exp(logits - m).sum(1))).astype(np.float32)
    top = np.argsort(-logits, axis=1, kind="stable").astype(np.int16)
    embed = lambda texts: model.embed(list(texts))  # noqa: E731
    return CandidateMap(
        kind="grid", vocabulary=NAMES, text=text, logit_scale=scale, features=feats,
        log_norm=log_norm, top_classes=top, entropy=rng.random(N).astype(np.float32),
        stderr=rng.random(N).astype(np.float32), pwkl=rng.random(N).astype(np.float32),
        num_views=rng.integers(1, 9, N).astype(np.int32),
        positions=np.c_[rng.random((N, 2)) * 10, rng.random(N)].astype(np.float32),
        text_encoder=embed,
    )  # fmt: skip


def _queries(n: int) -> list[BatchQuery]:
    rng = np.random.default_rng(1)
    free = ["somewhere to sit", "a red mug", "where I sleep", "a screen", "something green"]
    out = []
    for i in range(n):
        text = str(rng.choice(NAMES)) if i % 2 else f"{rng.choice(free)} {i % 7}"
        places = tuple(map(tuple, rng.random((i % 3, 2)) * 10)) if i % 4 == 0 else ()
        out.append(BatchQuery(text, places))
    return out


def test_batch_rows_equal_one_at_a_time_calls(grid_map: CandidateMap) -> None:
    queries = _queries(1000)
    config = BatchConfig(attempts=3, k=4)
    table = plan_batch(grid_map, queries, config).to_pylist()
    assert len({r["query_index"] for r in table}) == 1000
    by_key: dict[tuple, list[int]] = {}
    for r in table:
        by_key.setdefault((r["query_index"], r["strategy"], r["criterion"]), []).append(
            r["candidate"]
        )
    deterministic = [s for s in config.strategies if not STRATEGIES[s].random]
    for qi in range(0, 1000, 37):  # a sample of the queries, every strategy and criterion
        q = queries[qi]
        for name in deterministic:
            for criterion in config.criteria if STRATEGIES[name].uses_set else (None,):
                visited: list[int] = []
                expected = []
                for _ in range(config.attempts):
                    if name == "no_replan" and (visited or q.visited_at):
                        expected.append(-1)
                        continue
                    choice = next_goal(grid_map, q.text, visited, config=ReplanConfig(strategy=name, criterion=criterion or "confidence", k=config.k), visited_at=q.visited_at)  # fmt: skip
                    expected.append(choice.candidate)
                    if choice.candidate < 0:
                        break
                    visited.append(choice.candidate)
                expected += [-1] * (config.attempts - len(expected))
                assert by_key[(qi, name, criterion)] == expected, (qi, q, name, criterion)


def test_ranking_rows_and_free_text_method(grid_map: CandidateMap) -> None:
    queries = [BatchQuery("sofa"), BatchQuery("somewhere to sit")]
    rows = plan_batch(grid_map, queries, BatchConfig(top=5)).to_pylist()
    ranking = [r for r in rows if r["strategy"] == RANKING]
    assert [r["attempt"] for r in ranking] == [1, 2, 3, 4, 5] * 2
    assert ranking[0]["method"] == "vocabulary"
    assert ranking[5]["method"].startswith("joins the vocabulary")
    confs = [r["confidence"] for r in ranking[:5]]
    assert confs == sorted(confs, reverse=True)
    first = next_goal(grid_map, "somewhere to sit", [])
    assert ranking[5]["candidate"] == first.candidate


def test_same_batch_same_bytes(grid_map: CandidateMap) -> None:
    def dump() -> bytes:
        sink = io.BytesIO()
        pq.write_table(plan_batch(grid_map, _queries(60), BatchConfig(seed=3)), sink)
        return sink.getvalue()

    assert dump() == dump()


def test_query_files(tmp_path) -> None:
    (tmp_path / "q.txt").write_text("# queries\nchair\n\na red mug\n")
    assert read_queries(tmp_path / "q.txt") == [BatchQuery("chair"), BatchQuery("a red mug")]
    (tmp_path / "q.csv").write_text('query,visited\nchair,"1,2;3.5,-4"\nsofa,\n')
    assert read_queries(tmp_path / "q.csv") == [
        BatchQuery("chair", ((1.0, 2.0), (3.5, -4.0))),
        BatchQuery("sofa"),
    ]
    (tmp_path / "bad.csv").write_text('query,visited\nchair,"1;2"\n')
    with pytest.raises(ReplanError, match="line 2"):
        read_queries(tmp_path / "bad.csv")
    with pytest.raises(ReplanError, match="oracle"):
        BatchConfig(strategies=("oracle",))
    # the travel rules need each attempt walked from the last goal: care eval plays them
    with pytest.raises(ReplanError, match="a batch does not walk"):
        BatchConfig(strategies=("max_confidence", "nearest_topk"))
    assert not any(STRATEGIES[s].travel for s in BatchConfig().strategies)
