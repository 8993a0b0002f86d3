"""Building-scale grid fusion under a memory budget: a synthetic floor of ``--size`` metres.

A camera 3 m up looks straight down and sweeps the floor row by row (boustrophedon, 20%
overlap, a little jitter so cells are not aligned with the views); each view is 640x480
with a 24x32x512 feature map, written with the project's store writer (as ``care ingest``
does). At 5 cm a covered floor holds 400 cells per square metre: 100 m x 100 m is ~4M
cells, whose streaming state alone (5.7 KB a cell) is ~23 GB.

``build_grid`` then runs in a fresh process under ``--memory-budget`` (8 GB by default)
and prints its time, passes and peak resident memory. With ``--compare`` (the default
below 20 m) the same store is also fused without a budget and with a budget small enough
for several passes, and the two maps are compared column by column.

Run: ``python bench/scale.py --size 10`` (a minute), ``python bench/scale.py --size 100``
(the whole floor: tens of minutes and ~20 GB of disk under ``--workdir``).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import shutil
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from bench.docs_section import add_docs_flag, recorded

H, W, FH, FW, D = 480, 640, 24, 32, 512
K = np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]])
HEIGHT = 3.0


def _poses(size: float, rng: np.random.Generator) -> list[np.ndarray]:
    """Straight-down cameras covering a size x size floor with 20% overlap."""
    foot_x, foot_y = W / K[0, 0] * HEIGHT, H / K[1, 1] * HEIGHT
    xs = np.arange(foot_x / 2, size - foot_x / 2 + 1e-9, 0.8 * foot_x)
    ys = np.arange(foot_y / 2, size - foot_y / 2 + 1e-9, 0.8 * foot_y)
    rot = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])  # x right, y down, z to floor
    poses = []
    for j, y in enumerate(ys):
        for x in xs if j % 2 == 0 else xs[::-1]:
            pose = np.eye(4)
            pose[:3, :3] = rot
            pose[:3, 3] = [x + rng.uniform(-0.02, 0.02), y + rng.uniform(-0.02, 0.02), HEIGHT]
            poses.append(pose)
    return poses


def write_floor(path: Path, size: float, seed: int = 0) -> int:
    """The synthetic floor store; returns its number of views (reused when complete)."""
    from care_maps.core.frames import Frame
    from care_maps.core.store import EncoderInfo, Store, StoreWriter

    if (path / "meta.json").is_file():
        return Store(path).num_views
    shutil.rmtree(path, ignore_errors=True)
    rng = np.random.default_rng(seed)
    text = rng.normal(size=(100, D)).astype(np.float32)
    text /= np.linalg.norm(text, axis=1, keepdims=True)
    names = tuple(f"class {i}" for i in range(100))
    poses = _poses(size, rng)
    depth = np.full((H, W), HEIGHT, np.float32)  # a flat floor seen from straight above
    from tqdm import tqdm

    with StoreWriter(path, EncoderInfo("bench", "1", D, names)) as writer:
        for i, pose in enumerate(tqdm(poses, desc="write floor store", unit="view")):
            rgb = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
            feats = text[rng.integers(0, 100)] + 0.3 * rng.normal(size=(FH, FW, D))
            feats /= np.linalg.norm(feats, axis=-1, keepdims=True)
            writer.add(Frame(i, rgb, depth, K, pose), feats.astype(np.float16))
        writer.set_text(names, text)
        writer.commit({"source": "bench/scale"})
    return len(poses)


def _fuse_child(store: str, budget: int | None, cells_per_pass: int | None, queue) -> None:
    import pyarrow.parquet as pq

    from bench.rss import peak_rss_mb
    from care_maps.fuse.grid import GridConfig, build_grid
    from care_maps.fuse.grid import cells_per_pass as capacity_of
    from care_maps.runtime.execution import Execution
    from care_maps.runtime.malloc import keep_freed_memory
    from care_maps.runtime.threads import Work, use_threads

    use_threads(Work.FUSE)
    keep_freed_memory()
    run = Execution(overwrite=True, memory_budget=budget, cells_per_pass=cells_per_pass)
    capacity = capacity_of(run, D, 100)
    t0 = time.perf_counter()
    path = build_grid(Path(store), GridConfig(stride=1), run=run)
    seconds = time.perf_counter() - t0
    cells = pq.read_metadata(path).num_rows
    queue.put((seconds, cells, capacity, peak_rss_mb()))


def fuse(store: Path, budget: int | None, cells_per_pass: int | None = None) -> tuple:
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    proc = ctx.Process(target=_fuse_child, args=(str(store), budget, cells_per_pass, queue))
    proc.start()
    out = queue.get()
    proc.join()
    return out


def _compare(a, b) -> str:
    """'bit for bit' or the largest relative difference per float column."""
    worst = []
    for name in a.column_names:
        x, y = a.column(name), b.column(name)
        if x.equals(y):
            continue
        xs = np.asarray(x.to_pylist(), dtype=np.float64)
        ys = np.asarray(y.to_pylist(), dtype=np.float64)
        same = (xs == ys) | (np.isinf(xs) & np.isinf(ys))
        rel = np.abs(xs - ys)[~same] / np.maximum(np.abs(xs[~same]), 1e-30)
        worst.append(f"{name}: {int((~same).sum())} values differ, max rel {rel.max():.1e}")
    return "bit for bit" if not worst else "; ".join(worst)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=float, default=10.0, help="floor edge in metres")
    parser.add_argument("--memory-budget", type=float, default=8.0, help="GiB")
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/care-bench-scale"))
    parser.add_argument("--compare", action=argparse.BooleanOptionalAction, default=None)
    add_docs_flag(parser)
    args = parser.parse_args()
    with recorded("scale", write=not args.no_docs):
        import pyarrow.parquet as pq

        store = args.workdir / f"floor-{args.size:g}m"
        t0 = time.perf_counter()
        views = write_floor(store, args.size)
        print(
            f"floor {args.size:g} m x {args.size:g} m: {views} views ({time.perf_counter() - t0:.0f} s to write)"
        )
        budget = int(args.memory_budget * 2**30)
        print("| run | budget | cells | cells per pass | passes | s | views/s | peak RSS MiB |")
        print("| --- | --- | --- | --- | --- | --- | --- | --- |")

        def row(label: str, budget_text: str, result: tuple) -> None:
            seconds, cells, capacity, peak = result
            passes = -(-cells // capacity)
            print(
                f"| {label} | {budget_text} | {cells:,} | {capacity:,} | {passes} | {seconds:.0f} | "
                f"{views / seconds:.1f} | {peak:,.0f} |"
            )

        bounded = fuse(store, budget)
        row("bounded", f"{args.memory_budget:g} GiB", bounded)
        compare = args.compare if args.compare is not None else args.size < 20
        if compare:
            one = pq.read_table(store / "cells.parquet")
            views_bytes = (store / "cell_views.parquet").read_bytes()
            several = fuse(store, None, cells_per_pass=max(1, bounded[1] // 5))
            row("5 passes", "cells_per_pass", several)
            five = pq.read_table(store / "cells.parquet")
            unbounded = fuse(store, 1 << 50)
            row("unbounded", "none", unbounded)
            whole = pq.read_table(store / "cells.parquet")
            print(f"\nbounded (5 passes) vs unbounded map: {_compare(whole, five)}")
            print(f"budget run vs unbounded map: {_compare(whole, one)}")
            same = (store / "cell_views.parquet").read_bytes() == views_bytes
            print(f"cell_views.parquet byte-identical across runs: {same}")


if __name__ == "__main__":
    main()
