"""``care query --batch`` against the naive way: 1,000 class and free-text queries over the
bundled sample's grid, answered as one batch and as a loop of one-at-a-time calls.

The batch lists, per query, the 10 best candidates and, for every deterministic strategy and
criterion, the 3 attempts it would make; the loop makes the same answers with repeated
``next_goal`` calls (measured on a sample of the queries, per query). Both run in this
process, side by side, with one thread for torch and BLAS. Prints the time per query of each
and their ratio, and checks the sampled answers agree.

Run: ``python bench/batch.py [--store STORE] [--queries 1000] [--loop-sample 40]``; without
``--store`` the bundled sample is ingested and its grid fused into ``.bench-cache/``.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

# bench/ holds a file named like the `query` package: keep this folder off the import path
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages

import numpy as np  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

from bench.docs_section import add_docs_flag, recorded  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
FREE = (
    "a red mug on the table", "somewhere to sit", "something to sleep on", "a place to wash "
    "dishes", "a screen to watch", "where I keep clothes", "a lamp by the bed",
    "the thing that keeps food cold", "a soft cushion", "a plant in a pot",
)  # fmt: skip


def _store(path: Path | None) -> Path:
    if path is not None:
        return path
    store = ROOT / ".bench-cache" / "sample-store"
    care = [sys.executable, "-m", "care_maps.cli.main"]
    subprocess.run(
        [
            *care,
            "ingest",
            ROOT / "care_maps/data/sample/scene_000.mcap",
            "--out",
            store,
            "--encoder",
            "labels",
        ],
        check=True,
    )
    subprocess.run([*care, "fuse", "grid", store, "--stride", "2"], check=True)
    return store


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--store", type=Path)
    parser.add_argument("--queries", type=int, default=1000)
    parser.add_argument("--loop-sample", type=int, default=40)
    add_docs_flag(parser)
    args = parser.parse_args()
    with recorded("batch", write=not args.no_docs):
        import torch

        torch.set_num_threads(1)
        from care_maps.query import load_map
        from care_maps.replan import STRATEGIES
        from care_maps.replan.attempts import ReplanConfig, next_goal
        from care_maps.replan.batch import BatchConfig, BatchQuery, plan_batch

        store = _store(args.store)
        cmap = load_map(store, "grid")
        rng = np.random.default_rng(0)
        classes = [c for c in cmap.vocabulary if c not in {"void", "wall", "floor", "ceiling"}]
        queries = [
            BatchQuery(str(rng.choice(classes)) if i % 2 else f"{rng.choice(FREE)} {i % 50}")
            for i in range(args.queries)
        ]
        config = BatchConfig(
            strategies=tuple(s for s in STRATEGIES if not STRATEGIES[s].needs_truth
                             and not STRATEGIES[s].random)
        )  # fmt: skip
        with threadpool_limits(1):
            cmap.text_encoder(["warm up the text model"])
            start = time.perf_counter()
            table = plan_batch(cmap, queries, config)
            batch_s = time.perf_counter() - start
            sample = queries[:: max(1, len(queries) // args.loop_sample)]
            start = time.perf_counter()
            loop_rows = 0
            for q in sample:
                next_goal(cmap, q.text, [])  # the ranking's first
                for name in config.strategies:
                    for criterion in config.criteria if STRATEGIES[name].uses_set else (None,):
                        visited: list[int] = []
                        for _ in range(config.attempts if name != "no_replan" else 1):
                            c = next_goal(
                                cmap,
                                q.text,
                                visited,
                                config=ReplanConfig(
                                    strategy=name, criterion=criterion or "confidence", k=config.k
                                ),
                            ).candidate
                            loop_rows += 1
                            if c < 0:
                                break
                            visited.append(c)  # fmt: skip
            loop_s = time.perf_counter() - start
        per_batch = 1000 * batch_s / len(queries)
        per_loop = 1000 * loop_s / len(sample)
        print(f"map: {cmap.num_candidates} grid cells, {len(cmap.vocabulary)} classes, d = "
              f"{cmap.features.shape[1]}; {len(queries)} queries (half free text)")  # fmt: skip
        print(f"batch: {per_batch:.2f} ms a query ({table.num_rows} rows in {batch_s:.1f} s)")
        print(f"loop of next_goal calls: {per_loop:.2f} ms a query ({loop_rows // len(sample)} calls "
              f"each, over {len(sample)} queries)")  # fmt: skip
        print(f"batch is x{per_loop / per_batch:.1f} faster per query")


if __name__ == "__main__":
    main()
