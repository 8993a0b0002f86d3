"""Every output of ``care run`` stays what it was: a digest of each file, against the digests
recorded in ``tests/data/outputs.json``.

Two runs: the bundled sample (ground truth, both maps, the whole evaluation) and a user's own
recording (third-party living-room frames written as MCAP, a real CLIP checkpoint, no ground
truth). A file's digest is the SHA-256 of its bytes, except where the bytes carry what is not
output: a Parquet file is digested by its schema (with the metadata we write) and its values,
not the writer's version string; a PNG by its pixels, not the plotting library's name; a
Rerun file by its rows (entity, time and components), not its row ids, log times or start
time; a JSON file by its values with each recorded path cut to its file name. A change that moves any value fails here; a deliberate one updates the JSON with
``CARE_UPDATE_DIGESTS=1``.

The digests hold under ``requirements.lock`` (the versions they were made with: Parquet
bytes, float sums and PNGs change with library releases). In an environment of other
versions the tests skip and name the packages that differ; the tests of values elsewhere
hold on any supported version.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support.frames import load_livingroom

DIGESTS = Path(__file__).parents[1] / "data" / "outputs.json"
OFFLINE = {**os.environ, "HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"}
PATH_KEYS = frozenset({"path", "source", "weights", "precomputed", "text_file"})
RRD_SKIP = ("RowId", "log_time", "log_tick", "RecordingInfo:start_time")


def _parquet(path: Path) -> str:
    import pyarrow.parquet as pq

    table = pq.read_table(path).combine_chunks()
    meta = table.schema.metadata or {}
    digest = hashlib.sha256(repr(sorted(meta.items())).encode())
    for field, column in zip(table.schema, table.columns, strict=True):
        digest.update(repr((field.name, str(field.type))).encode())
        digest.update(repr(column.to_pylist()).encode())
    return digest.hexdigest()


def _png(path: Path) -> str:
    import numpy as np
    from PIL import Image

    with Image.open(path) as image:
        pixels = np.asarray(image)
    return hashlib.sha256(
        repr((pixels.shape, str(pixels.dtype))).encode() + pixels.tobytes()
    ).hexdigest()


def _rrd(path: Path) -> str:
    from rerun.chunk import RrdReader

    rows = []
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        columns = [
            (name, column.to_pylist())
            for name, column in zip(batch.schema.names, batch.columns, strict=True)
            if not any(skip in name for skip in RRD_SKIP)
        ]
        for i in range(batch.num_rows):
            row = (chunk.entity_path, [(n, v[i]) for n, v in columns if v[i] is not None])
            rows.append(hashlib.sha256(repr(row).encode()).hexdigest())
    return hashlib.sha256("".join(sorted(rows)).encode()).hexdigest()


def _where(value: object) -> object:
    """A JSON value with each path we record replaced by its file name: where the test's
    temporary folder lies is not output."""
    if isinstance(value, dict):
        return {
            k: Path(v).name if k in PATH_KEYS and isinstance(v, str) else _where(v)
            for k, v in value.items()
        }
    if isinstance(value, list):
        return [_where(v) for v in value]
    return value


def _json(path: Path) -> str:
    value = _where(json.loads(path.read_text()))
    return hashlib.sha256(json.dumps(value, sort_keys=True).encode()).hexdigest()


def _digest(path: Path) -> str:
    reader = {".parquet": _parquet, ".png": _png, ".rrd": _rrd, ".json": _json}.get(path.suffix)
    if reader is not None:
        return reader(path)
    return hashlib.sha256(path.read_bytes()).hexdigest()


def digests(folder: Path) -> dict[str, str]:
    """Relative path -> digest of every file under ``folder``."""
    return {
        str(p.relative_to(folder)): _digest(p) for p in sorted(folder.rglob("*")) if p.is_file()
    }


def _care(*args: object, cwd: Path | None = None) -> None:
    cmd = [sys.executable, "-m", "care_maps.cli.main", *map(str, args)]
    done = subprocess.run(cmd, capture_output=True, text=True, env=OFFLINE, timeout=900, cwd=cwd)
    assert done.returncode == 0, done.stderr[-2000:]


LOCK = Path(__file__).resolve().parents[2] / "requirements.lock"


def _off_the_lock() -> list[str]:
    """The locked packages installed here at another version (or missing)."""
    from importlib import metadata

    off = []
    for line in LOCK.read_text().splitlines():
        if "==" not in line or line.startswith("#"):
            continue
        name, wanted = line.strip().split("==")
        try:
            have = metadata.version(name)
        except metadata.PackageNotFoundError:
            have = "missing"
        if have != wanted:
            off.append(f"{name} {have} (locked {wanted})")
    return off


@pytest.fixture(autouse=True)
def _under_the_lock() -> None:
    off = _off_the_lock()
    if off and os.environ.get("CARE_UPDATE_DIGESTS") != "1":
        pytest.skip(
            f"byte digests are checked under requirements.lock; this environment has "
            f"{len(off)} other versions: {', '.join(off[:5])}"
        )


def _check(name: str, folder: Path) -> None:
    found = digests(folder)
    recorded = json.loads(DIGESTS.read_text()) if DIGESTS.is_file() else {}
    if os.environ.get("CARE_UPDATE_DIGESTS") == "1":
        recorded[name] = found
        DIGESTS.parent.mkdir(exist_ok=True)
        DIGESTS.write_text(json.dumps(recorded, indent=1, sort_keys=True) + "\n")
        return
    expected = recorded[name]
    changed = sorted(k for k in expected.keys() | found.keys() if expected.get(k) != found.get(k))
    assert not changed, f"{name}: outputs changed: {changed}"


@pytest.mark.slow
def test_sample_run_outputs_unchanged(tmp_path: Path) -> None:
    _care("run", "--out", tmp_path / "run")
    _check("sample", tmp_path / "run")


@pytest.mark.slow
def test_own_recording_outputs_unchanged(
    tmp_path: Path, livingroom_root: Path, save_tiny_clip
) -> None:
    from care_maps.core.frames import Frame
    from care_maps.ingest.write import write_recording

    frames = []
    for f in load_livingroom(livingroom_root, 40)[::5]:
        K = f.K.copy()
        K[:2] /= 4
        K[:2, 2] = (f.K[:2, 2] - 1.5) / 4
        rgb, depth = f.rgb[::4, ::4].copy(), f.depth_m[::4, ::4].copy()
        frames.append(Frame(f.stamp_ns, rgb, depth, K, f.cam_to_world))
    write_recording(tmp_path / "kitchen.mcap", frames, fmt="mcap")
    save_tiny_clip(tmp_path / "weights", layers=2)
    # paths as given on the command line go into the store's fingerprint: relative ones, so
    # that where the temporary folder lies is not output
    _care(
        "run", "kitchen.mcap", "--out", "out", "--encoder", "clip", "--weights", "weights",
        "--vocabulary", "chair,sofa,table", cwd=tmp_path,
    )  # fmt: skip
    _check("own", tmp_path / "out")


@pytest.mark.slow
def test_bench_store_outputs_unchanged(tmp_path: Path) -> None:
    """The benchmark's synthetic store (written through the store writer, as `bench/fuse.py`
    writes it) and its grid, fused with reading ahead and in one thread."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "bench_fuse", DIGESTS.parents[2] / "bench" / "fuse.py"
    )
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    one, serial = tmp_path / "bench" / "one", tmp_path / "bench" / "serial"
    for store in (one, serial):
        bench._write_store(store, num_frames=6, room=4.0, d=64, seed=2)
    _care("fuse", "grid", one)
    _care("fuse", "grid", serial, "--read-ahead", 0)
    _check("bench", tmp_path / "bench")
