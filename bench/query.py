"""Latency of a query plus one replan over precomputed columns (the paper claims < 15 ms).

A synthetic map of 5,000 instances (d = 512, n = 200 classes) with every column of the
map-table contract; the replan is min stderr over the top-k confidence set (k = 8) and, for
comparison, over the top-k category set. Prints:

- a single live call, ``next_goal(map, query, visited=[first])`` (target < 1 ms);
- per query, amortised over a batch of 1,000 queries as array operations (target < 50 us);
- the naive way: a Python loop of single calls over the same 1,000 queries.

Run: ``python bench/query.py``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

# this file is named like the `query` package: keep its own folder off the import path
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import numpy as np  # noqa: E402

from query.confidence import confidence  # noqa: E402
from query.map import MEASURES, CandidateMap  # noqa: E402
from replan.attempts import next_goal  # noqa: E402
from replan.strategies import STRATEGIES, Situation, best_of, candidate_set  # noqa: E402

N, D, N_CLASSES, K, BATCH = 5_000, 512, 200, 8, 1_000
PAPER_MS = 15.0


def synthetic_map(seed: int = 0) -> CandidateMap:
    rng = np.random.default_rng(seed)
    text = rng.normal(size=(N_CLASSES, D)).astype(np.float32)
    text /= np.linalg.norm(text, axis=1, keepdims=True)
    feats = text[rng.integers(0, N_CLASSES, N)] + 0.5 * rng.normal(size=(N, D)).astype(np.float32)
    feats /= np.linalg.norm(feats, axis=1, keepdims=True)
    logits = 100.0 * feats.astype(np.float64) @ text.T.astype(np.float64)
    log_norm = np.logaddexp.reduce(logits, axis=1)
    top = np.argsort(-logits, axis=1, kind="stable")[:, :100].astype(np.int16)
    return CandidateMap(
        kind="instances", vocabulary=tuple(f"class{i}" for i in range(N_CLASSES)), text=text,
        logit_scale=100.0, features=feats.astype(np.float16).astype(np.float32),
        log_norm=log_norm.astype(np.float32), top_classes=top,
        entropy=rng.random(N).astype(np.float32), stderr=rng.random(N).astype(np.float32),
        pwkl=rng.random(N).astype(np.float32), num_views=rng.integers(1, 6, N).astype(np.int32),
        positions=rng.random((N, 3)).astype(np.float32),
    )  # fmt: skip


def batch_query_replan(cmap: CandidateMap, ys: np.ndarray, criterion: str) -> np.ndarray:
    """First attempt and one min-stderr replan for every query of the batch at once."""
    conf = confidence(cmap, ys)
    available = np.ones(conf.shape, bool)
    first, _ = best_of(conf, available, conf, maximise=True)
    available[np.arange(len(ys)), first] = False
    rank = cmap.class_rank(ys, limit=K) if criterion == "category" else None
    cset = candidate_set(criterion, conf, available, K, rank)
    columns = {m: cmap.column(m) for m in MEASURES}
    return STRATEGIES["min_stderr"].rule(Situation(conf, available, cset, columns)).candidate


def _best_of(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    cmap = synthetic_map()
    rng = np.random.default_rng(1)
    ys = rng.integers(0, N_CLASSES, BATCH)
    first = int(np.argmax(confidence(cmap, ys[:1])[0]))
    cmap.class_rank(ys[:1])  # the class index is built once per map, at first use
    print(f"map: {N} instances, d={D}, {N_CLASSES} classes; replan: min stderr, k={K}")
    for criterion in ("confidence", "category"):
        live = _best_of(
            lambda c=criterion: next_goal(cmap, int(ys[0]), [first], criterion=c, k=K), 50
        )
        batch = _best_of(lambda c=criterion: batch_query_replan(cmap, ys, c), 5)
        naive = (
            _best_of(
                lambda c=criterion: [
                    next_goal(cmap, int(y), [0], criterion=c, k=K) for y in ys[:200]
                ],
                1,
            )
            / 200
        )
        per_query = batch / BATCH
        print(
            f"{criterion:>10} set | single live call {live * 1e3:7.3f} ms (target < 1 ms, "
            f"paper {PAPER_MS:.0f} ms: x{PAPER_MS / (live * 1e3):.0f}) | batch of {BATCH}: "
            f"{per_query * 1e6:6.1f} us/query (target < 50 us; loop of single calls "
            f"{naive * 1e6:7.1f} us/query, x{naive / per_query:.1f})"
        )


if __name__ == "__main__":
    main()
