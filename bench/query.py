"""Whole-building query latency: open a grid map, first attempt, replans (the paper: < 15 ms).

Synthetic grid maps of 5k, 50k, 500k and 1M cells (d = 512, 100 classes, 5 cm cells on a
square floor, one class per 1 m block) are written with the fusion's own writers
(``care_maps.fuse.measures.candidate_columns`` chunk by chunk, ``care_maps.core.store.open_writer``,
``care_maps.fuse.sidecar.SidecarWriter``) and cached under ``--workdir``. Each size then runs in a
fresh process (so memory figures are its own) and prints:

- ``load_map`` time and the resident memory it added;
- a live ``next_goal`` (min stderr over the top-k confidence set, k = 8, 1 m exclusion):
  first attempt, replan after 1 failure, replan after 10 failures; for a vocabulary class
  and for free text (``query.resolve_text`` with the offline sentence model, then the same
  calls; the text embedding is included);
- side by side, the plain way (``--legacy-max`` cells at most): the whole Parquet table
  decoded, confidence by an (N, d) product, and each failed attempt's exclusion a pass over
  every cell (``care_maps.replan.attempts.available_after``).

Targets: < 15 ms per attempt at 1M cells for a vocabulary class, < 50 ms for free text. Run: ``python bench/query.py`` (``--sizes 5000 50000`` for a quick look).

A second table times the goal a navigation stack gets for an attempt
(``care_maps.query.goals.FreeSpace.approach``: the free cell nearest the object that keeps 0.3 m from
every obstacle) on floors of rooms with walls and clutter, at the same sizes and at 4M cells
(100 m x 100 m): the clearance computed around the goal against a distance transform of the
whole floor (the plain way), the two goals compared.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import sys
import time
from pathlib import Path

# this file is named like the `query` package: keep its own folder off the import path
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from bench.docs_section import add_docs_flag, recorded  # noqa: E402

D, N_CLASSES, K, CELL, BLOCK = 512, 100, 8, 0.05, 20
SIZES = (5_000, 50_000, 500_000, 1_000_000)
FREE_TEXT = "somewhere to sit down"


def write_map(folder: Path, n_cells: int, seed: int = 0) -> Path:
    """A synthetic grid store: cells.parquet (+ sidecar) and text.parquet, written in chunks."""
    import pyarrow as pa

    from care_maps.core.store import TEXT_SCHEMA, open_writer, write_table_atomic
    from care_maps.fuse.accumulate import COLUMN_CHUNK
    from care_maps.fuse.measures import candidate_columns, candidate_metadata
    from care_maps.fuse.sidecar import SidecarWriter, sidecar_path

    if (folder / "cells.parquet").is_file() and (folder / "text.parquet").is_file():
        return folder
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    names = [f"class {i}" for i in range(N_CLASSES)]
    names[:4] = ["chair", "sofa", "table", "bed"]
    text = rng.normal(size=(N_CLASSES, D)).astype(np.float32)
    text /= np.linalg.norm(text, axis=1, keepdims=True)
    side = int(np.ceil(np.sqrt(n_cells)))
    ids = np.arange(n_cells)
    ix, iy = ids // side, ids % side
    block_class = rng.integers(0, N_CLASSES, (side // BLOCK + 1, side // BLOCK + 1))
    md = {
        **candidate_metadata(names, 100.0, "bench"),
        b"care.grid.cell_size": repr(CELL).encode(),
        b"care.grid.origin": b"[0.0, 0.0]",
        b"care.grid.shape": f"[{side}, {side}]".encode(),
        b"care.schema_version": b"1",
    }
    path = folder / "cells.parquet"
    sidecar = SidecarWriter(sidecar_path(path), n_cells, D, N_CLASSES, N_CLASSES, md)
    writer = None
    for lo in range(0, n_cells, COLUMN_CHUNK):
        rows = slice(lo, min(lo + COLUMN_CHUNK, n_cells))
        m = rows.stop - lo
        cls = block_class[ix[rows] // BLOCK, iy[rows] // BLOCK]
        feats = text[cls] + rng.normal(size=(m, D)).astype(np.float32) * 0.04
        table = candidate_columns(
            feats, text, 100.0, num_views=rng.integers(1, 30, m), stderr=rng.random(m),
            pwkl=rng.random(m), first_id=lo, with_log_confidence=True,
        )  # fmt: skip
        sidecar.write(table)
        table = table.drop_columns(["log_confidence"])
        for name, values in (
            ("x", (ix[rows] + 0.5) * CELL), ("y", (iy[rows] + 0.5) * CELL),
            ("z_max", rng.random(m)),
        ):  # fmt: skip
            table = table.append_column(name, pa.array(values.astype(np.float32)))
        if writer is None:
            writer = open_writer(path, table.schema.with_metadata(md))
        writer.write_table(table.replace_schema_metadata(md))
    writer.close()
    sidecar.commit()
    write_table_atomic(
        pa.table({"name": names, "embedding": list(text)}, schema=TEXT_SCHEMA),
        folder / "text.parquet",
    )
    return folder


def _best(fn, repeat: int = 5) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times) * 1e3


def _visits(cmap, y: int, n: int) -> list[int]:
    """The first n attempts of an episode where every attempt fails."""
    from care_maps.replan.attempts import ReplanConfig, next_goal

    visited: list[int] = []
    for _ in range(n):
        visited.append(
            next_goal(cmap, y, visited, config=ReplanConfig(strategy="min_stderr", k=K)).candidate
        )
    return visited


def _legacy_goal(cmap, y: int, visited: list[int]) -> int:
    """next_goal as it was: confidence by the (N, d) product, exclusion by full passes."""
    from care_maps.query.map import MEASURES
    from care_maps.replan.attempts import available_after
    from care_maps.replan.strategies import STRATEGIES, Situation, best_of, candidate_set

    conf = np.exp(cmap.log_confidence_of(np.array([y])))
    available = np.ones_like(conf, dtype=bool)
    for v in visited:
        available = available_after(available, np.array([v]), cmap.positions, 1.0)
    if not visited:
        return int(best_of(conf, available, conf, maximise=True)[0][0])
    cset = candidate_set("confidence", conf, available, K)
    columns = {m: cmap.column(m) for m in MEASURES}
    return int(
        STRATEGIES["min_stderr"].rule(Situation(conf, available, cset, columns)).candidate[0]
    )


def _run_size(folder: str, n_cells: int, legacy: bool, queue) -> None:
    from bench.rss import current_rss_mb
    from care_maps.runtime.threads import Work, use_threads

    use_threads(Work.QUERY)
    import pyarrow.dataset  # noqa: F401  (pq.read_table imports it at first use: 0.5 s)

    from care_maps.query import load_map, resolve_text
    from care_maps.query.map import map_from_table
    from care_maps.replan.attempts import ReplanConfig, next_goal

    path = Path(folder)
    resolve_text_warm = resolve_text  # the sentence model loads at first use: not timed
    before = current_rss_mb()
    t0 = time.perf_counter()
    cmap = load_map(path, "grid")
    load_ms = (time.perf_counter() - t0) * 1e3
    load_mb = current_rss_mb() - before
    y = cmap.class_id("sofa")
    resolve_text_warm(cmap, FREE_TEXT)
    visited = _visits(cmap, y, 10)
    out = {"load_ms": load_ms, "load_mb": load_mb}
    for label, query in (("vocabulary", "sofa"), ("free text", FREE_TEXT)):

        def goal(v: list[int], q: str = query) -> int:
            cls = resolve_text(cmap, q).class_id
            return next_goal(
                cmap, cls, v, config=ReplanConfig(strategy="min_stderr", k=K)
            ).candidate

        out[label] = [_best(lambda v=v: goal(v)) for v in ([], visited[:1], visited)]
    if legacy:
        import pyarrow.parquet as pq

        before = current_rss_mb()
        t0 = time.perf_counter()
        old = map_from_table(pq.read_table(path / "cells.parquet"), cmap.text, "grid")
        out["legacy_load_ms"] = (time.perf_counter() - t0) * 1e3
        out["legacy_load_mb"] = current_rss_mb() - before
        out["legacy"] = [
            _best(lambda v=v: _legacy_goal(old, y, v), 3) for v in ([], visited[:1], visited)
        ]
        same = [_legacy_goal(old, y, visited[:i]) == visited[i] for i in range(len(visited))]
        out["legacy_agrees"] = sum(same)
    queue.put(out)


def _floor(n: int, seed: int = 0, clutter: float = 0.01):
    """A square floor of about ``n`` 5 cm cells: 4 m rooms walled on two sides with a 1 m
    door each, and ``clutter`` of the cells obstacles, all seen."""
    from care_maps.fuse.layout import GridLayout
    from care_maps.query.goals import FreeSpace

    side = int(np.sqrt(n))
    ix, iy = (a.reshape(-1) for a in np.meshgrid(np.arange(side), np.arange(side), indexing="ij"))
    room = int(4 / CELL)
    door = (ix % room > room // 2) & (ix % room < room // 2 + int(1 / CELL))
    wall = (ix % room == 0) & ~(iy % room > 20) | (iy % room == 0) & ~door
    clutter = np.random.default_rng(seed).random(ix.size) < clutter
    return FreeSpace.from_cells(GridLayout(CELL, (0.0, 0.0), (side, side)), ix, iy, wall | clutter)


def bench_goals(sizes) -> None:
    """Goal poses: clearance around each goal against the whole floor's distance transform
    (computed once per ``care query`` before), the goals compared whole."""
    from dataclasses import dataclass

    from scipy import ndimage

    from care_maps.query.goals import FreeSpace, GoalConfig

    @dataclass(frozen=True)
    class WholeFloor(FreeSpace):
        """The plain way: every cell's clearance from one transform of the whole floor."""

        whole: np.ndarray | None = None

        def clearance(self, xs: slice, ys: slice, margin: int) -> tuple[np.ndarray, float]:
            return self.whole[xs, ys], np.inf

    print("\n## goal pose for an attempt (0.3 m clearance, 1 m reach), 20 objects")
    print("| cells | around the goal ms | whole floor ms (plain) | speed-up | same goals |")
    print("| --- | --- | --- | --- | --- |")
    config = GoalConfig()
    for n in sizes:
        space = _floor(n)
        side = space.layout.shape[0] * CELL
        targets = [tuple(xy) for xy in np.random.default_rng(1).uniform(0.5, side - 0.5, (20, 2))]
        t = time.perf_counter()
        goals = [space.approach(xy, config) for xy in targets]
        ours = (time.perf_counter() - t) / len(targets) * 1e3
        t = time.perf_counter()
        whole = ndimage.distance_transform_edt(~space.blocked) * CELL
        before = WholeFloor(space.layout, space.free, space.blocked, whole)
        old = [before.approach(xy, config) for xy in targets]
        old_ms = (time.perf_counter() - t) * 1e3  # the transform once: a query's first goal
        same = sum(a == b for a, b in zip(goals, old, strict=True))
        print(
            f"| {space.layout.shape[0] ** 2:,} | {ours:.2f} | {old_ms:,.0f} | "
            f"x{old_ms / ours:,.0f} | {same}/{len(goals)} |"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=list(SIZES))
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/care-bench-query"))
    parser.add_argument(
        "--legacy-max", type=int, default=500_000, help="largest map also run the plain way"
    )
    add_docs_flag(parser)
    args = parser.parse_args()
    full = not args.no_docs and set(SIZES) <= set(args.sizes)  # fewer sizes: a quick look
    with recorded("query", write=full):
        print(
            f"grid maps: d={D}, {N_CLASSES} classes, {CELL} m cells; replan: min stderr, k={K}, 1 m"
        )
        print(
            "| cells | load_map ms | load MiB | query | first ms | replan ms | replan after 10 ms |"
            " old way: load ms / MiB | old first / replan / after 10 ms | speed-up after 10 |"
        )
        print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
        ctx = mp.get_context("spawn")
        for n in args.sizes:
            folder = write_map(args.workdir / f"grid-{n}", n)
            queue = ctx.Queue()
            legacy = n <= args.legacy_max
            proc = ctx.Process(target=_run_size, args=(str(folder), n, legacy, queue))
            proc.start()
            r = queue.get()
            proc.join()
            for label in ("vocabulary", "free text"):
                first, replan, after10 = r[label]
                old = ""
                if legacy and label == "vocabulary":
                    lf, lr, l10 = r["legacy"]
                    old = (
                        f"{r['legacy_load_ms']:,.0f} / {r['legacy_load_mb']:,.0f} | "
                        f"{lf:.1f} / {lr:.1f} / {l10:.1f} (same picks {r['legacy_agrees']}/10) | "
                        f"x{l10 / after10:.0f}"
                    )
                else:
                    old = " | | "
                print(
                    f"| {n:,} | {r['load_ms']:.0f} | {r['load_mb']:.0f} | {label} | {first:.2f} | "
                    f"{replan:.2f} | {after10:.2f} | {old} |"
                )
        bench_goals([*args.sizes, 4_000_000])


if __name__ == "__main__":
    main()
