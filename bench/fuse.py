"""Fusion benchmarks: grid throughput vs a per-pixel loop, linear vs pairwise pwKL, memory.

Run ``python bench/fuse.py`` (``--quick`` for a smaller run). Every figure runs on one
thread for torch and BLAS alike (:mod:`care_maps.runtime.threads`). Prints four tables:

0. ``care fuse grid`` end to end (:func:`care_maps.fuse.grid.build_grid` on a store written with the
   project's store writer: read, fuse, write cell_views and cells): views/s at 640x480,
   stride 1, d = 512, 100 classes (targets at 200 views: >= 28 in one thread, >= 40 the
   default way), on today's 0.1 store (``png-lists``) and the default encoding
   (``raw-zstd``, :mod:`care_maps.core.codecs`) side by side with their size a view, all in one thread
   and the default way (views decoded and sampled ahead on two background threads, while
   the main thread merges), the maps compared value for value, peak memory per occupied cell, as the
   slope between a small and a large floor (target <= 15 KB);

1. pixels fused per second with d = 512 features at pixel strides 8, 2 and 1, the
   vectorised grid fusion (``care_maps.fuse.cells.view_samples`` + ``care_maps.fuse.accumulate.CandidateSums``)
   against a naive per-pixel Python loop on the same frames, their ratio (target:
   >= 100x at stride 1), and the bound the samples' class logits put on it;
2. mean pairwise symmetric KL, linear identity (streamed view by view) against the pairwise
   form, time and peak memory for m = 5, 50 and 500 views per candidate;
3. peak memory of grid fusion against the number of frames: bounded by occupied cells.
"""

from __future__ import annotations

import argparse
import hashlib
import math
import multiprocessing as mp
import os
import sys
import time
import tracemalloc
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.docs_section import add_docs_flag, recorded
from bench.rss import peak_rss_mb
from care_maps.core.frames import Frame
from care_maps.fuse.accumulate import CandidateSums
from care_maps.fuse.cells import CellIndex, view_samples
from care_maps.fuse.config import GridConfig
from care_maps.fuse.keys import STORE_KEY
from care_maps.fuse.measures import pwkl_linear, pwkl_pairwise, pwkl_terms
from care_maps.runtime.malloc import keep_freed_memory

H, W = 480, 640
FH, FW = 24, 32
STORES = "v3"
"""Tag of the synthetic stores under ``--workdir`` (v3: camera-like colours, not noise; the
store's encoding follows in the name)."""
TARGETS: dict[str, tuple[str, str, bool]] = {}
"""The performance targets as each table measures them: name -> (value, target, met)."""
K = np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]])
CELL = 0.05
SIGMA_Z = GridConfig().sigma_z


def room_frame(rng: np.random.Generator, room: float = 5.0) -> Frame:
    """A camera 1.2-1.6 m up, pitched down 15-35 degrees, inside a box room with a ceiling."""
    yaw = rng.uniform(0, 2 * np.pi)
    pitch = rng.uniform(np.radians(15), np.radians(35))
    forward = np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), -np.sin(pitch)])
    right = np.array([np.sin(yaw), -np.cos(yaw), 0.0])
    down = np.cross(forward, right)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([right, down, forward], axis=1)
    pose[:3, 3] = [*rng.uniform(0.5, room - 0.5, 2), rng.uniform(1.2, 1.6)]
    # depth = distance along each pixel ray (optical z = 1) to the nearest plane of the room
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u, float)], -1)
    dirs = rays @ pose[:3, :3].T
    depth = np.full((H, W), np.inf)
    # walls off the 5 cm lattice: a wall exactly on a cell boundary splits its pixels between
    # two cells by rounding noise, which no real recording does
    lo = 0.0137
    surface = np.zeros((H, W), np.int64)
    planes = ((0, (lo, lo + room)), (1, (lo, lo + room)), (2, (0.0, 2.6)))
    for axis, bounds in planes:
        d = dirs[..., axis]
        safe = np.where(np.abs(d) > 1e-9, d, 1e-9)
        for side, plane in enumerate(bounds):
            t = (plane - pose[axis, 3]) / safe
            nearer = (t > 0) & (t < depth)
            depth = np.where(nearer, t, depth)
            surface[nearer] = 2 * axis + side
    return Frame(
        0,
        _colours(rng, surface, pose[:3, 3] + depth[..., None] * dirs),
        depth.astype(np.float32),
        K,
        pose,
    )


def _colours(rng: np.random.Generator, surface: np.ndarray, points: np.ndarray) -> np.ndarray:
    """A camera-like image: each wall, the floor and the ceiling a colour, shaded by a
    pattern in world coordinates, plus sensor noise. (White noise, which the benchmark
    used before, is the worst case of JPEG: a 600 KB image that decodes 2-3x slower than
    a photograph, so reading the store dominated the end-to-end figure.)"""
    palette = np.array(
        [[200, 180, 150], [190, 170, 140], [170, 190, 200], [160, 180, 190], [120, 90, 60],
         [235, 235, 230]], np.float64,
    )  # fmt: skip
    shade = 25 * np.sin(3.1 * points[..., 0] + 1.7 * points[..., 2]) * np.cos(2.3 * points[..., 1])
    rgb = palette[surface] + shade[..., None] + rng.normal(0, 3, (*surface.shape, 3))
    return np.clip(rgb, 0, 255).astype(np.uint8)


def _load() -> str:
    """The 1-minute load average: on a shared machine every figure is read against it."""
    return f"{os.getloadavg()[0]:.1f}"


def _target(name: str, value: str, target: str, met: bool) -> None:
    TARGETS[name] = (f"{value} (load {_load()})", target, met)


def room_features(rng: np.random.Generator, d: int) -> np.ndarray:
    f = rng.normal(size=(FH, FW, d)).astype(np.float32)
    return f / np.linalg.norm(f, axis=-1, keepdims=True)


def _grid_sums(text: np.ndarray) -> CandidateSums:
    """The state as ``build_grid``'s first pass makes it: limited to the cells the default
    memory budget holds (and so reserved at once, see :class:`CandidateSums`)."""
    from care_maps.fuse.grid import cells_per_pass
    from care_maps.runtime.execution import Execution

    limit = cells_per_pass(Execution(), text.shape[1], len(text))
    return CandidateSums(text.shape[1], text, 100.0, limit=limit)


def _fuse_vectorised(frames, feats, text, stride: int) -> tuple[CandidateSums, float, float, float]:
    """The streaming pass; returns the sums, the CPU seconds in view_samples and in the
    sums, and the wall seconds of the whole pass."""
    index = CellIndex()
    sums = _grid_sums(text)
    samples_s = sums_s = 0.0
    wall = time.perf_counter()
    for frame, feat in zip(frames, feats, strict=True):
        t0 = time.process_time()
        s = view_samples(
            frame, feat, cell_size=CELL, stride=stride, z_min=-0.2, z_max=2.0, sigma_z=SIGMA_Z,
            text=text,
        )  # fmt: skip
        t1 = time.process_time()
        sums.add(index.lookup(s.keys), s.weight, s.feature, s.dots)
        samples_s += t1 - t0
        sums_s += time.process_time() - t1
    return sums, samples_s, sums_s, time.perf_counter() - wall


def _fuse_naive(frames, feats, text, stride: int) -> dict:
    """The same sums, the plain way: a Python loop over pixels, then over (view, cell) samples."""
    samples: dict = defaultdict(lambda: [0, 0.0, 0.0])
    for view, (frame, feat) in enumerate(zip(frames, feats, strict=True)):
        T = frame.cam_to_world
        for v in range(0, H, stride):
            for u in range(0, W, stride):
                z = float(frame.depth_m[v, u])
                if z <= 0:
                    continue
                p = T @ np.array([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z, 1.0])
                if not -0.2 <= p[2] <= 2.0:
                    continue
                key = (math.floor(p[0] / CELL), math.floor(p[1] / CELL), view)
                s = samples[key]
                s[0] += 1
                s[1] += math.exp(-z * z / (2 * 2.5**2))
                s[2] = s[2] + feat[v * FH // H, u * FW // W]
    cells: dict = {}
    for (ix, iy, _), (_count, w, fsum) in samples.items():
        f = fsum / np.linalg.norm(fsum)
        logits = 100.0 * (text @ f)
        P = np.exp(logits - logits.max())
        P /= P.sum()
        a = np.log(np.maximum(P, 1e-12))
        c = cells.setdefault((ix, iy), [0.0, 0.0, 0.0, 0.0, 0, 0.0, 0.0, 0.0])
        c[0] += w
        c[1] += w * w
        c[2] = c[2] + w * f
        c[3] = c[3] + w * f * f
        c[4] += 1
        c[5] = c[5] + P * a
        c[6] = c[6] + P
        c[7] = c[7] + a
    return cells


def _fused_pixels(frame: Frame, stride: int) -> int:
    """Valid depth pixels inside the height band: the pixels both methods actually fuse."""
    from care_maps.geometry.transforms import backproject, transform_points

    points, _ = backproject(frame.depth_m, frame.K, stride)
    z = transform_points(frame.cam_to_world, points)[:, 2]
    return int(((z >= -0.2) & (z <= 2.0)).sum())


def _logits_floor(frames, feats, text, stride: int) -> float:
    """Seconds for the samples' class logits alone: min(samples, patches) x d x n per view.

    pwKL needs every (view, cell) sample's class distribution, so this matrix product is
    work any implementation does: the speed-up over the loop cannot exceed the loop's time
    over this one.
    """
    sizes = [
        view_samples(
            f, x, cell_size=CELL, stride=stride, z_min=-0.2, z_max=2.0, sigma_z=SIGMA_Z
        ).size
        for f, x in zip(frames, feats, strict=True)
    ]
    text32 = text.astype(np.float32)
    t0 = time.process_time()
    for feat, k in zip(feats, sizes, strict=True):
        flat = feat.reshape(-1, feat.shape[-1])
        _ = flat[: min(k, len(flat))] @ text32.T
    return time.process_time() - t0


def bench_throughput(
    num_frames: int, strides: tuple[int, ...], d: int = 512, naive_pixels: int = 60_000
) -> None:
    """Both methods on the same frames; the naive loop on as many as fit ``naive_pixels``.

    Both columns time the streaming pass (every view into the per-cell sums); turning the
    sums into the map's columns is once per map, the same for both, and shown on its own.
    The vectorised pass is split into its two stages, per frame: the view's samples
    (geometry, features, logits) and adding them to the sums (memory-bound, including the
    first touch of the state's pages).

    Times are this process's CPU seconds (every pool runs one thread, so that is one core's
    work); the ratio in wall seconds is printed beside. On a quiet machine the two agree; on
    a shared one the wall clock counts the other processes' turns, which hurt the
    memory-bound vectorised pass more than the interpreter loop (at load 6.5 the naive loop
    took 2.3x its CPU time in wall time, the vectorised pass 2.9x).
    """
    rng = np.random.default_rng(0)
    frames = [room_frame(rng) for _ in range(num_frames)]
    feats = [room_features(rng, d) for _ in range(num_frames)]
    text = room_features(rng, d).reshape(-1, d)[:100]
    _fuse_vectorised(frames[:1], feats[:1], text, 8)  # warm up
    print(
        f"\n## Grid fusion throughput (d={d}, {H}x{W} frames, {CELL} m cells, 100 classes, 1 thread)"
    )
    print(
        "| stride | method | frames | fused pixels | CPU ms/frame (samples + sums) | pixels/s | "
        "ratio (wall) | map columns s | logits alone ms/frame (ratio bound) | load |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for stride in strides:
        per_frame = [_fused_pixels(f, stride) for f in frames]
        sums, samples_s, sums_s, fast_wall = _fuse_vectorised(frames, feats, text, stride)
        fast_s = samples_s + sums_s
        t0 = time.process_time()
        sums.columns()
        columns_s = time.process_time() - t0
        fast = sum(per_frame) / fast_s
        naive_frames = int(np.clip(naive_pixels // max(np.mean(per_frame), 1), 1, num_frames))
        t0, wall = time.process_time(), time.perf_counter()
        _fuse_naive(frames[:naive_frames], feats[:naive_frames], text, stride)
        slow_s, slow_wall = time.process_time() - t0, time.perf_counter() - wall
        slow = sum(per_frame[:naive_frames]) / slow_s
        wall_ratio = (slow_wall / naive_frames) / (fast_wall / num_frames)
        floor_s = _logits_floor(frames, feats, text, stride)
        bound = sum(per_frame) / floor_s / slow
        ms = 1e3 / num_frames
        if stride == 1:
            _target("fusion maths vs per-pixel loop, stride 1 (CPU time)", f"x{fast / slow:.0f} "
                    f"(wall x{wall_ratio:.0f})", ">= x100", fast / slow >= 100)  # fmt: skip
        print(
            f"| {stride} | vectorised (view_samples + CandidateSums) | {num_frames} | "
            f"{sum(per_frame)} | {fast_s * ms:.1f} ({samples_s * ms:.1f} + {sums_s * ms:.1f}) | "
            f"{fast:,.0f} | {fast / slow:.1f}x ({wall_ratio:.1f}x) | {columns_s:.2f} | "
            f"{floor_s * ms:.2f} ({bound:.0f}x) | {_load()} |"
        )
        print(
            f"| {stride} | naive per-pixel Python loop | {naive_frames} | "
            f"{sum(per_frame[:naive_frames])} | {slow_s * 1e3 / naive_frames:.0f} | {slow:,.0f} | "
            f"1x | | | {_load()} |"
        )


def _pwkl_inputs(rng, n_cand: int, m: int, n: int, j: int) -> np.ndarray:
    """Per-view distributions of view j for every candidate, deterministic in (m, j)."""
    logits = np.random.default_rng([m, j]).normal(size=(n_cand, n)) * 3
    P = np.exp(logits - logits.max(1, keepdims=True))
    return P / P.sum(1, keepdims=True)


def _linear(n_cand: int, m: int, n: int) -> np.ndarray:
    S = np.zeros((n_cand, n))
    Q = np.zeros((n_cand, n))
    A = np.zeros((n_cand, n))
    for j in range(m):  # streamed: one view of every candidate at a time
        s, q, a = pwkl_terms(_pwkl_inputs(None, n_cand, m, n, j))
        S += s
        Q += q
        A += a
    return pwkl_linear(S, Q, A, np.full(n_cand, m))


def _pairwise(n_cand: int, m: int, n: int) -> np.ndarray:
    views = np.stack([_pwkl_inputs(None, n_cand, m, n, j) for j in range(m)], axis=1)
    return pwkl_pairwise(list(views))


def _measure(fn, *args) -> tuple[float, float, np.ndarray]:
    t0 = time.perf_counter()
    out = fn(*args)
    seconds = time.perf_counter() - t0
    tracemalloc.start()
    fn(*args)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return seconds, peak / 2**20, out


def bench_pwkl(n_cand: int, n: int, sizes: tuple[int, ...]) -> None:
    print(f"\n## pwKL: linear identity vs pairwise ({n_cand} candidates, {n} classes)")
    print(
        "| m views | linear s | pairwise s | speed-up | linear peak MiB | pairwise peak MiB | max rel diff |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for m in sizes:
        tl, ml, lin = _measure(_linear, n_cand, m, n)
        tp, mp_, pair = _measure(_pairwise, n_cand, m, n)
        rel = np.max(np.abs(lin - pair) / np.maximum(np.abs(pair), 1e-12))
        print(f"| {m} | {tl:.4f} | {tp:.4f} | {tp / tl:.1f}x | {ml:.1f} | {mp_:.1f} | {rel:.1e} |")


def _peak_child(num_frames: int, d: int, stride: int, queue) -> None:
    from care_maps.runtime.threads import Work, use_threads

    use_threads(Work.FUSE)
    keep_freed_memory()
    rng = np.random.default_rng(1)
    text = room_features(rng, d).reshape(-1, d)[:100]
    index = CellIndex()
    sums = CandidateSums(d, text, 100.0)
    for _ in range(num_frames):  # frames made and dropped one at a time, as a store streams them
        s = view_samples(
            room_frame(rng),
            room_features(rng, d),
            cell_size=CELL,
            stride=stride,
            z_min=-0.2,
            z_max=2.0,
            sigma_z=SIGMA_Z,
            text=text,
        )
        sums.add(index.lookup(s.keys), s.weight, s.feature, s.dots)
    peak = peak_rss_mb()
    queue.put((index.size, sums.nbytes / 2**20, peak))


def bench_memory(counts: tuple[int, ...], d: int = 512, stride: int = 4) -> None:
    print(
        f"\n## Grid fusion memory vs frames (d={d}, stride {stride}, 5 x 5 m room, fresh process each)"
    )
    print("| frames | occupied cells | accumulator MiB | peak RSS MiB |")
    print("| --- | --- | --- | --- |")
    ctx = mp.get_context("spawn")
    for n in counts:
        queue = ctx.Queue()
        proc = ctx.Process(target=_peak_child, args=(n, d, stride, queue))
        proc.start()
        cells, state, peak = queue.get()
        proc.join()
        print(f"| {n} | {cells} | {state:.0f} | {peak:.0f} |")


def _write_store(
    path: Path, num_frames: int, room: float, d: int, seed: int, encoding: str | None = None
) -> Path:
    """A store of synthetic views through the project's writer (as ``care ingest`` writes),
    in ``encoding`` (:class:`care_maps.core.codecs.StoreEncoding`; default the writer's)."""
    from care_maps.core.codecs import StoreEncoding
    from care_maps.core.store import EncoderInfo, StoreWriter

    rng = np.random.default_rng(seed)
    text = room_features(np.random.default_rng(99), d).reshape(-1, d)[:100]
    names = tuple(f"class {i}" for i in range(100))
    how = {} if encoding is None else {"encoding": StoreEncoding(encoding)}
    with StoreWriter(path, EncoderInfo("bench", "1", d, names), **how) as writer:
        for _ in range(num_frames):
            writer.add(room_frame(rng, room), room_features(rng, d).astype(np.float16))
        writer.set_text(names, text)
        writer.commit({"source": "bench"})
    return path


def _build_child(store: str, read_ahead: int, queue) -> None:
    from bench.rss import current_rss_mb
    from care_maps.fuse.grid import GridConfig, build_grid
    from care_maps.runtime.execution import Execution
    from care_maps.runtime.threads import Work, use_threads

    use_threads(Work.FUSE)
    keep_freed_memory()
    import pyarrow as pa
    import pyarrow.parquet as pq

    # program start, untimed like the torch import: pyarrow imports pandas (0.4-1 s) at the
    # process's first Arrow -> NumPy conversion, whichever step makes it
    pa.array([0.0]).to_numpy()
    base = current_rss_mb()
    t0, c0 = time.perf_counter(), time.process_time()
    run = Execution(overwrite=True, read_ahead=read_ahead)
    path = build_grid(Path(store), GridConfig(stride=1), run=run)
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    cells = pq.read_metadata(path).num_rows
    views = Path(store, "cell_views.parquet")
    samples = pq.read_metadata(views).num_rows
    digest = _values_digest(path, views)
    queue.put((seconds, cpu, cells, base, peak_rss_mb(), views.stat().st_size / 2**20, samples,
               digest))  # fmt: skip


def _values_digest(*paths: Path) -> str:
    """sha256 of tables' columns, values and schema, without the metadata that names the
    store they came from (a map records its store's checksums: two encodings of one store
    differ there by design)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    digest = hashlib.sha256()
    for path in paths:
        table = pq.read_table(path).combine_chunks()
        keep = {k: v for k, v in (table.schema.metadata or {}).items() if k != STORE_KEY}
        table = table.replace_schema_metadata(keep)
        sink = pa.BufferOutputStream()  # Arrow IPC: the values' bytes, the schema with them
        with pa.ipc.new_stream(sink, table.schema) as out:
            out.write_table(table)
        digest.update(sink.getvalue())
    return digest.hexdigest()


def _build(store: Path, read_ahead: int) -> tuple:
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    proc = ctx.Process(target=_build_child, args=(str(store), read_ahead, queue))
    proc.start()
    out = queue.get()
    proc.join()
    return out


def _store_kb_per_view(store: Path, frames: int) -> float:
    """What ingest wrote, a view: the views and features tables."""
    return (
        sum((store / f"{t}.parquet").stat().st_size for t in ("views", "features")) / frames / 1e3
    )


def bench_end_to_end(sizes: tuple[tuple[int, float], ...], workdir: Path, d: int = 512) -> None:
    """``build_grid`` end to end in a fresh process per store and way, ``sizes`` (views,
    room edge in m), on the same views stored two ways (today's 0.1 store, ``png-lists``, and
    the default, ``raw-zstd``: :mod:`care_maps.core.codecs`): all in one thread (``read_ahead=0``: one
    core) and as ``care fuse grid`` runs by default (the store decoded and each view's
    samples made on two background threads while the main thread merges,
    :func:`care_maps.fuse.grid._view_samples`), the four maps compared value for value; memory as the
    slope between the first and the last store (the fixed cost of the program cancels)."""
    import shutil

    from care_maps.core.codecs import StoreEncoding
    from care_maps.runtime.execution import Execution

    ahead = Execution().read_ahead
    encodings = (StoreEncoding.PNG_LISTS, StoreEncoding.RAW_ZSTD)
    print(f"\n## care fuse grid end to end (640x480, stride 1, d={d}, 100 classes)")
    print(
        "| views | store | store KB/view | occupied cells | samples/view | way | s (CPU s) | "
        "views/s (per CPU s) | cell_views MB/view | peak RSS MiB (before build) | peak KB/cell | "
        "same map | load |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    runs = []
    for frames, room in sizes:
        label = f"{room:g} m room, {frames} views"
        digests, kb = [], {}
        for encoding in encodings:
            store = workdir / f"fuse-{frames}-{room:g}-{STORES}-{encoding.value}"
            if not (store / "meta.json").is_file():
                shutil.rmtree(store, ignore_errors=True)
                _write_store(store, frames, room, d, seed=2, encoding=encoding.value)
            kb[encoding] = _store_kb_per_view(store, frames)
            name = "today's (png-lists)" if encoding is StoreEncoding.PNG_LISTS else "raw-zstd"
            for way, read_ahead in (("one thread", 0), (f"default (read_ahead={ahead})", ahead)):
                seconds, cpu, cells, base, peak, views_mb, samples, digest = _build(
                    store, read_ahead
                )
                digests.append(digest)
                rate = frames / seconds
                if encoding is StoreEncoding.RAW_ZSTD and frames == 200 and room == 5.0:
                    target = 28 if read_ahead == 0 else 40
                    _target(
                        f"views/s end to end, {label}, {way}",
                        f"{rate:.1f} ({frames / cpu:.1f} per CPU second)", f">= {target}",
                        rate >= target,
                    )  # fmt: skip
                print(
                    f"| {label} | {name} | {kb[encoding]:.0f} | {cells:,} | "
                    f"{samples / frames:,.0f} | {way} | {seconds:.1f} ({cpu:.1f}) | {rate:.1f} "
                    f"({frames / cpu:.1f}) | {views_mb / frames:.2f} | {peak:,.0f} ({base:,.0f}) "
                    f"| {(peak - base) * 1024 / cells:.1f} | "
                    f"{'yes' if digest == digests[0] else '**no**'} | {_load()} |"
                )
        ratio = kb[StoreEncoding.RAW_ZSTD] / kb[StoreEncoding.PNG_LISTS]
        _target(f"store size a view, {label}", f"x{ratio:.2f} of today's", "<= x1.5", ratio <= 1.5)
        _target(f"same map from both stores, both ways, {label}", "", "", len(set(digests)) == 1)
        runs.append((cells, peak))
    (c1, p1), (c2, p2) = runs[0], runs[-1]
    if c2 > c1:
        slope = (p2 - p1) * 2**20 / (c2 - c1) / 1024
        _target("peak memory per occupied cell (slope)", f"{slope:.1f} KB", "<= 15 KB", slope <= 15)
        print(
            f"\nmarginal peak memory per occupied cell (slope between the first and the last, "
            f"default way): {slope:.1f} KB (target <= 15 KB)"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller sizes (about a minute)")
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/care-bench-fuse"))
    parser.add_argument(
        "--only", choices=("end-to-end", "throughput", "pwkl", "memory"), help="one table"
    )
    add_docs_flag(parser)
    args = parser.parse_args()
    full = not (args.no_docs or args.quick or args.only)  # one table is not the whole run
    with recorded("fuse", write=full):
        from care_maps.runtime.threads import Work, use_threads

        # like the naive loop: one core, torch and BLAS alike (and fair on a shared machine)
        use_threads(Work.FUSE)
        keep_freed_memory()  # as the care program does, for both methods
        args.workdir.mkdir(parents=True, exist_ok=True)
        quick = args.quick
        runs = {
            "end-to-end": lambda: bench_end_to_end(
                ((40, 5.0), (60, 14.0)) if quick else ((40, 5.0), (200, 5.0), (200, 14.0)), args.workdir
            ),
            "throughput": lambda: bench_throughput(num_frames=10, strides=(8, 1))
            if quick
            else bench_throughput(num_frames=40, strides=(8, 2, 1), naive_pixels=200_000),
            "pwkl": lambda: bench_pwkl(n_cand=50 if quick else 200, n=100 if quick else 200,
                                       sizes=(5, 50, 500)),
            "memory": lambda: bench_memory((10, 40) if quick else (10, 40, 160)),
        }  # fmt: skip
        for name, run in runs.items():
            if args.only in (None, name):
                run()
        if TARGETS:
            print("\n## Targets, side by side (1-minute load average at each figure)")
            print("| figure | measured | target | met |")
            print("| --- | --- | --- | --- |")
            for name, (value, target, met) in TARGETS.items():
                print(f"| {name} | {value} | {target} | {'yes' if met else '**no**'} |")


if __name__ == "__main__":
    main()
