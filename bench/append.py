"""Maps that grow: one more run of N views appended to a store of 200 and of 2,000 views,
against rebuilding from every view, side by side in one run.

For each size a store of synthetic views is written through the project's writer (a camera
in a box room with camera-like colours, d = 512 features, 100 classes: ``bench/fuse.py``'s
views) and its grid built (untimed). Then, timed:

- **append the run**: the store with N more views (``care ingest RUN --out STORE --append``
  without the recording's reading, :func:`care_maps.ingest.runs.append_frames`: the earlier
  views copied as stored, the new ones encoded, the maps carried over, committed in one step);
- **grow the grid**: ``care fuse grid`` on it, which continues the grid's saved state with
  the N new views (:mod:`care_maps.fuse.grid_state`);
- **rebuild the grid**: the same grid fused from every view (``--overwrite``), the way there
  is without a saved state, and the naive way to take a run in. Its map is the grown one,
  byte for byte (checked).

Appending should grow with N, not with the store: the grid's growth at 2,000 views is near
its growth at 200, while the rebuild grows tenfold. (The store's append copies the earlier
views' bytes: that part grows with the store, at disk speed.)

    python bench/append.py [--sizes 200 2000] [--added 20] [--no-docs]
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.docs_section import add_docs_flag, recorded  # noqa: E402
from bench.fuse import room_features, room_frame  # noqa: E402

D = 512
CLASSES = 100
ROOMS = {200: 5.0, 2000: 14.0}
"""The room's side (m) for each store size, as ``bench/fuse.py`` sizes its floors."""
GRID_STRIDE = 2


def _text() -> tuple[tuple[str, ...], np.ndarray]:
    text = room_features(np.random.default_rng(99), D).reshape(-1, D)[:CLASSES]
    return tuple(f"class {i}" for i in range(CLASSES)), text


def _write(path: Path, views: int, room: float, seed: int) -> Path:
    from care_maps.core.store import EncoderInfo, StoreWriter

    names, text = _text()
    rng = np.random.default_rng(seed)
    with StoreWriter(path, EncoderInfo("bench", "1", D, names)) as writer:
        for _ in range(views):
            writer.add(room_frame(rng, room), room_features(rng, D).astype(np.float16))
        writer.set_text(names, text)
        writer.commit({"source": "bench", "fingerprint": f"bench-{seed}"})
    return path


def _append(store: Path, added: int, room: float, seed: int) -> None:
    """What ``care ingest --append`` does once the run is read: the store with one more run."""
    from care_maps.ingest.runs import append_frames

    rng = np.random.default_rng(seed)
    frames, features = [], []
    for _ in range(added):
        frames.append(room_frame(rng, room))
        features.append(room_features(rng, D).astype(np.float16))
    append_frames(store, frames, features, name=f"run {seed}", fingerprint=f"bench-{seed}")


def _timed(work) -> float:
    t0 = time.perf_counter()
    work()
    return time.perf_counter() - t0


def _row(views: int, added: int, work: Path) -> tuple[float, float, float, bool]:
    from care_maps.fuse.grid import GridConfig, build_grid
    from care_maps.runtime.execution import Execution

    room = ROOMS.get(views, 5.0)
    config = GridConfig(stride=GRID_STRIDE)
    quiet = Execution(progress=False)
    store = _write(work / f"store{views}", views, room, seed=1)
    build_grid(store, config, run=quiet)
    append_s = _timed(lambda: _append(store, added, room, seed=2))
    grow_s = _timed(lambda: build_grid(store, config, run=quiet))
    grown = {p.name: p.read_bytes() for p in store.glob("cell*.parquet")}
    rebuild_s = _timed(
        lambda: build_grid(store, config, run=Execution(overwrite=True, progress=False))
    )
    same = grown == {p.name: p.read_bytes() for p in store.glob("cell*.parquet")}
    shutil.rmtree(store)
    return append_s, grow_s, rebuild_s, same


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[200, 2000])
    parser.add_argument("--added", type=int, default=20, help="views in the appended run")
    add_docs_flag(parser)
    args = parser.parse_args()
    from care_maps.runtime.threads import Work, use_threads

    use_threads(Work.FUSE)
    with recorded("append", write=not args.no_docs), tempfile.TemporaryDirectory() as tmp:
        print(
            f"One run of {args.added} views appended to a store, its grid grown against rebuilt "
            f"(640x480 views, d = {D}, {CLASSES} classes, stride {GRID_STRIDE}; "
            f"{os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}):\n"
        )
        print("| views in the store | append the run (s) | grow the grid (s) | rebuild the grid (s) | rebuild / grow | same map |")  # fmt: skip
        print("| --- | --- | --- | --- | --- | --- |")
        for views in args.sizes:
            append_s, grow_s, rebuild_s, same = _row(views, args.added, Path(tmp))
            print(
                f"| {views} | {append_s:.2f} | {grow_s:.2f} | {rebuild_s:.2f} | "
                f"{rebuild_s / grow_s:.1f}x | {'yes' if same else 'NO'} |"
            )


if __name__ == "__main__":
    main()
