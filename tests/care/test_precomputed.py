"""Precomputed features written by pyarrow and polars (as another tool would), read by stamp."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from care_maps.core.encoders import EncoderOptions, make_encoder
from care_maps.core.encoders import precomputed as pre
from care_maps.core.encoders.precomputed import PrecomputedEncoder, text_path_for
from care_maps.core.errors import EncoderError
from care_maps.core.frames import Frame
from care_maps.core.store import Store, StoreWriter

STAMPS = [1_000_000_000 + i * 100_000_000 for i in range(6)]
FH, FW, D = 3, 4, 5


def _maps() -> np.ndarray:
    return np.random.default_rng(0).normal(size=(len(STAMPS), FH, FW, D)).astype(np.float32)


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _write(path: Path, maps: np.ndarray, stamps: list[int], **metadata: str) -> Path:
    table = pa.table(
        {
            "stamp_ns": pa.array(stamps, pa.int64()),
            "fh": pa.array([m.shape[0] for m in maps], pa.int16()),
            "fw": pa.array([m.shape[1] for m in maps], pa.int16()),
            "feature": pa.array(
                [m.ravel().astype(np.float16) for m in maps], pa.list_(pa.float16())
            ),
        }
    )
    if metadata:
        table = table.replace_schema_metadata({f"care.encoder.{k}": v for k, v in metadata.items()})
    pq.write_table(table, path, row_group_size=2)
    return path


@pytest.fixture
def feature_file(tmp_path: Path) -> Path:
    path = _write(tmp_path / "lseg.parquet", _maps()[::-1], STAMPS[::-1])  # any row order
    text = pa.table(
        {"name": ["chair", "table"], "embedding": [[2.0, 0, 0, 0, 0], [0, 3.0, 0, 0, 4.0]]}
    )
    pq.write_table(text, text_path_for(path))
    return path


def _frame(stamp: int) -> Frame:
    return Frame(
        stamp, np.zeros((6, 8, 3), np.uint8), np.ones((6, 8), np.float32), np.eye(3), np.eye(4)
    )


def _encoder(path: Path) -> PrecomputedEncoder:
    enc = make_encoder("precomputed", EncoderOptions(precomputed=path))
    assert isinstance(enc, PrecomputedEncoder)
    return enc


def test_views_found_by_stamp_within_tolerance(feature_file: Path) -> None:
    enc = _encoder(feature_file)
    assert (enc.dim, enc.name, enc.supports_crops) == (D, "precomputed", False)
    got = enc.encode_views(
        [_frame(STAMPS[4] + 400_000), _frame(STAMPS[1] - 999_000), _frame(STAMPS[0])]
    )
    ref = _unit(_maps()[[4, 1, 0]].astype(np.float16).astype(np.float32))
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, ref, atol=1e-6)
    assert enc.encode_views([]).shape == (0, 0, 0, D)


def test_polars_file_float32_large_list(tmp_path: Path) -> None:
    pl = pytest.importorskip("polars")
    maps = _maps()
    path = tmp_path / "other.parquet"
    pl.DataFrame(
        {
            "stamp_ns": pl.Series(STAMPS, dtype=pl.Int64),
            "fh": pl.Series([FH] * len(STAMPS), dtype=pl.Int32),
            "fw": pl.Series([FW] * len(STAMPS), dtype=pl.Int32),
            "feature": pl.Series([m.ravel().tolist() for m in maps], dtype=pl.List(pl.Float32)),
        }
    ).write_parquet(path)
    enc = _encoder(path)
    np.testing.assert_allclose(enc.encode_views([_frame(STAMPS[2])])[0], _unit(maps[2]), atol=1e-6)
    assert enc.version.startswith("other.parquet:")


def test_provenance_from_schema_metadata(tmp_path: Path) -> None:
    path = _write(tmp_path / "f.parquet", _maps(), STAMPS, name="lseg", version="demo_e200")
    assert _encoder(path).version.startswith("lseg:demo_e200@f.parquet:")


def test_reads_only_the_row_groups_it_needs(
    feature_file: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Streaming: stamps up front, then one row group of maps per lookup (spy on the real reader)."""
    calls: list[tuple[int, tuple[str, ...]]] = []
    real = pq.ParquetFile.read_row_group

    def spy(
        self: pq.ParquetFile, i: int, columns: list[str] | None = None, **kw: object
    ) -> pa.Table:
        calls.append((i, tuple(columns or ())))
        return real(self, i, columns=columns, **kw)

    monkeypatch.setattr(pq.ParquetFile, "read_row_group", spy)
    enc = _encoder(feature_file)
    assert enc._file.num_row_groups == 3
    feature_reads = [c for c in calls if "feature" in c[1]]
    assert [c for c in calls if c[1] == ("stamp_ns",)] == [(g, ("stamp_ns",)) for g in range(3)]
    assert len(feature_reads) == 1  # one group, to learn d
    calls.clear()
    # Rows were written newest first: group 0 holds STAMPS[5], STAMPS[4]; group 2 STAMPS[1], [0].
    enc.encode_views([_frame(STAMPS[5]), _frame(STAMPS[4])])
    enc.encode_views([_frame(STAMPS[0])])
    assert calls == [(0, ("fh", "fw", "feature")), (2, ("fh", "fw", "feature"))]


def test_text_side(feature_file: Path) -> None:
    enc = _encoder(feature_file)
    np.testing.assert_allclose(
        enc.encode_text(["table", "chair"]), [[0, 0.6, 0, 0, 0.8], [1, 0, 0, 0, 0]]
    )
    with pytest.raises(EncoderError, match=r"lseg\.text\.parquet: no embedding for 'sofa'"):
        enc.encode_text(["chair", "sofa"])
    text_path_for(feature_file).unlink()
    with pytest.raises(
        EncoderError, match=r"lseg\.text\.parquet: no text embeddings beside lseg\.parquet"
    ):
        enc.encode_text(["chair"])
    pq.write_table(
        pa.table({"name": ["chair"], "embedding": [[1.0, 0.0]]}), text_path_for(feature_file)
    )
    with pytest.raises(EncoderError, match=r"embeddings of length \[2\], features have d=5"):
        enc.encode_text(["chair"])


def test_missing_stamp_names_it(feature_file: Path) -> None:
    enc = _encoder(feature_file)
    with pytest.raises(
        EncoderError,
        match=r"lseg\.parquet: no precomputed features for image stamp 1050000000 ns "
        r"\(nearest 1000000000 ns is 50\.000 ms away, tolerance 1 ms\)",
    ):
        enc.encode_views([_frame(STAMPS[2]), _frame(1_050_000_000)])
    loose = PrecomputedEncoder(EncoderOptions(precomputed=feature_file), tolerance_ns=60_000_000)
    assert loose.encode_views([_frame(1_050_000_000)]).shape == (1, FH, FW, D)


def test_bad_files(tmp_path: Path) -> None:
    with pytest.raises(EncoderError, match=r"needs --precomputed FILE\.parquet"):
        make_encoder("precomputed", EncoderOptions())
    with pytest.raises(EncoderError, match=r"absent\.parquet: no such file"):
        _encoder(tmp_path / "absent.parquet")
    junk = tmp_path / "junk.parquet"
    junk.write_text("not parquet")
    with pytest.raises(EncoderError, match=r"junk\.parquet: not a readable Parquet file"):
        _encoder(junk)
    nocol = tmp_path / "nocol.parquet"
    pq.write_table(pa.table({"stamp_ns": [1], "feature": [[1.0]]}), nocol)
    with pytest.raises(
        EncoderError,
        match=r"nocol\.parquet: no column fh, fw; .*columns present: stamp_ns, feature",
    ):
        _encoder(nocol)
    dup = _write(tmp_path / "dup.parquet", _maps()[:2], [STAMPS[0], STAMPS[0]])
    with pytest.raises(EncoderError, match=r"stamp 1000000000 ns appears twice"):
        _encoder(dup)
    bad = tmp_path / "bad.parquet"
    pq.write_table(
        pa.table({"stamp_ns": [1], "fh": [2], "fw": [2], "feature": [[1.0, 2.0, 3.0]]}), bad
    )
    with pytest.raises(EncoderError, match=r"stamp 1: feature of length 3 is not fh \* fw \* d"):
        _encoder(bad)
    strings = tmp_path / "strings.parquet"
    pq.write_table(pa.table({"stamp_ns": [1], "fh": [1], "fw": [1], "feature": [["a"]]}), strings)
    with pytest.raises(
        EncoderError, match=r"column feature is list<.*string.*>, expected list<float16\|float32>"
    ):
        _encoder(strings)


def test_large_row_groups_refused(feature_file: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(pre, "MAX_ROW_GROUP_BYTES", 10)
    with pytest.raises(EncoderError, match=r"row group 0 holds .* MiB.*row_group_size=64"):
        _encoder(feature_file)


def test_store_round_trip(feature_file: Path, tmp_path: Path) -> None:
    """Features looked up here and written through the store come back as they went in."""
    enc = _encoder(feature_file)
    frames = [_frame(s) for s in STAMPS]
    maps = enc.encode_views(frames)
    with StoreWriter(tmp_path / "store", enc.info(["chair", "table"])) as writer:
        for frame, fmap in zip(frames, maps, strict=True):
            writer.add(frame, fmap)
        writer.set_text(["chair", "table"], enc.encode_text(["chair", "table"]))
        writer.commit({})
    store = Store(tmp_path / "store")
    assert store.encoder.name == "precomputed"
    back = np.stack([m for _, m in store.iter_features()]).astype(np.float32)
    np.testing.assert_allclose(
        back, _unit(_maps().astype(np.float16).astype(np.float32)), atol=2e-3
    )


@pytest.mark.slow
def test_cli_precomputed_store_from_listed_stamps(tmp_path: Path) -> None:
    """The documented path (docs/inputs.md, *Precomputed features*): list the stamps, compute features for them elsewhere (here: random),
    ingest; a missing text table fails before any frame; free text in the table joins the
    vocabulary, other text falls back to the sentence model and says so."""
    import json
    import subprocess
    import sys

    from care_maps.fuse.grid import GridConfig, build_grid

    rec = Path(__file__).resolve().parents[2] / "care_maps" / "data" / "sample" / "scene_000.mcap"
    care = [sys.executable, "-m", "care_maps.cli.main"]
    listed = subprocess.run([*care, "topics", rec, "--stamps"], capture_output=True, text=True)
    stamps = [int(s) for s in listed.stdout.split()]
    assert len(stamps) == 80
    rng = np.random.default_rng(2)
    feats = _write(
        tmp_path / "f.parquet", rng.normal(size=(80, 6, 8, D)).astype(np.float32), stamps
    )
    names = ["chair", "table", "sofa"]
    ingest = [*care, "ingest", rec, "--out", tmp_path / "store", "--encoder", "precomputed",
              "--precomputed", feats, "--vocabulary", ",".join(names)]  # fmt: skip
    early = subprocess.run(ingest, capture_output=True, text=True)
    assert early.returncode == 1
    assert "text embeddings" in early.stderr
    assert "ingest scene_000" not in early.stderr  # no frame was read
    emb = rng.normal(size=(4, D)).astype(np.float32)
    pq.write_table(
        pa.table({"name": [*names, "a red mug"], "embedding": [e.tolist() for e in emb]}),
        text_path_for(feats),
    )
    subprocess.run(ingest, capture_output=True, text=True, check=True)
    build_grid(tmp_path / "store", GridConfig(cell_size=0.1, stride=4))
    query = [*care, "query", tmp_path / "store", "--map", "grid", "--json"]
    mug = json.loads(
        subprocess.run([*query, "a red mug"], capture_output=True, text=True, check=True).stdout
    )
    assert mug["method"] == "joins the vocabulary [precomputed text encoder]"
    other = json.loads(
        subprocess.run([*query, "a lamp"], capture_output=True, text=True, check=True).stdout
    )
    assert other["method"].startswith("sentence")
