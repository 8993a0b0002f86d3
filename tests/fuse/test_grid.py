"""The grid map against a per-pixel reference written out plainly, on tiny hand-built stores."""

from __future__ import annotations

import json
import math
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

import duckdb
import numpy as np
import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from PIL import Image
from scipy.special import rel_entr, softmax
from scipy.stats import entropy as scipy_entropy
from statsmodels.stats.weightstats import DescrStatsW

from care_maps.core.errors import FuseError
from care_maps.core.frames import Frame
from care_maps.core.store import EncoderInfo, StoreWriter, read_table
from care_maps.fuse import grid as grid_module
from care_maps.fuse.grid import GridConfig, GridLayout, build_grid, grid_image
from care_maps.fuse.recompute import recompute_grid
from care_maps.fuse.schemas import CELL_VIEWS_FIELDS
from care_maps.fuse.sidecar import read_sidecar
from care_maps.runtime.execution import Execution
from tests.support.stores import GRID_DIM, GRID_NAMES, grid_frames, grid_store, grid_text, unit


def _reference(frames: list[tuple[Frame, np.ndarray]], cfg: GridConfig, text: np.ndarray) -> dict:
    """Per cell: fused feature, stderr, pwKL, entropy, views, from a plain loop over pixels.

    Depths go through the store's millimetre PNG and features through float16, so the
    frames are rounded the same way here.
    """
    samples: dict[tuple, dict] = defaultdict(lambda: {"f": [], "w": 0.0})
    for view, (frame, feats) in enumerate(frames):
        depth = np.round(frame.depth_m * 1000) / 1000
        height, width = depth.shape
        fh, fw = feats.shape[:2]
        k = frame.K
        for v in range(0, height, cfg.stride):
            for u in range(0, width, cfg.stride):
                z = float(depth[v, u])
                if z <= 0:
                    continue
                cam = np.array([(u - k[0, 2]) * z / k[0, 0], (v - k[1, 2]) * z / k[1, 1], z, 1.0])
                world = frame.cam_to_world @ cam
                if not cfg.z_min <= world[2] <= cfg.z_max:
                    continue
                cell = (math.floor(world[0] / cfg.cell_size), math.floor(world[1] / cfg.cell_size))
                s = samples[(cell, view)]
                s["f"].append(
                    feats[v * fh // height, u * fw // width].astype(np.float16).astype(np.float64)
                )
                s["w"] += (
                    math.exp(-(z**2) / (2 * cfg.sigma_z**2)) if cfg.distance_weighting else 1.0
                )
    per_cell: dict[tuple, list] = defaultdict(list)
    for (cell, _view), s in samples.items():
        f = unit(np.mean(s["f"], axis=0))
        per_cell[cell].append((f, np.float32(s["w"])))
    out = {}
    for cell, items in per_cell.items():
        f = np.array([i[0] for i in items])
        w = np.array([i[1] for i in items], dtype=np.float64)
        m = len(items)
        fused = unit((w[:, None] * f).sum(0) / w.sum()).astype(np.float16).astype(np.float64)
        P_views = softmax(cfg.logit_scale * f @ text.T, axis=1)
        P = softmax(cfg.logit_scale * fused @ text.T)
        if m >= 2:
            std = DescrStatsW(f, weights=w, ddof=0).std.mean()
            se = std / math.sqrt(w.sum() ** 2 / (w * w).sum())
            Pc = np.clip(P_views, 1e-12, None)
            kl = [
                0.5 * (rel_entr(Pc[a], Pc[b]).sum() + rel_entr(Pc[b], Pc[a]).sum())
                for a in range(m)
                for b in range(a + 1, m)
            ]
            pwkl = 2 * sum(kl) / (m * (m - 1))
        else:
            se = pwkl = math.inf
        out[cell] = {
            "views": m,
            "feature": fused,
            "stderr": se,
            "pwkl": pwkl,
            "entropy": scipy_entropy(P),
            "weight": w.sum(),
        }
    return out


def _by_cell(table) -> dict:
    md = GridLayout.from_table(table)
    cs = md.cell_size
    ix = table.column("ix").to_numpy() + round(md.origin[0] / cs)
    iy = table.column("iy").to_numpy() + round(md.origin[1] / cs)
    return {(int(a), int(b)): i for i, (a, b) in enumerate(zip(ix, iy, strict=True))}


@pytest.mark.parametrize(
    "cfg",
    [
        GridConfig(cell_size=0.1, logit_scale=20.0),
        GridConfig(
            cell_size=0.07, stride=2, distance_weighting=False, z_min=0.2, logit_scale=100.0
        ),
    ],
)
def test_streaming_equals_per_pixel_reference(tmp_path: Path, cfg: GridConfig) -> None:
    path = build_grid(grid_store(tmp_path / "s"), cfg)
    table = read_table(path)
    ref = _reference(grid_frames(4), cfg, grid_text().astype(np.float64))
    rows = _by_cell(table)
    assert set(rows) == set(ref)
    assert table.column("candidate_id").to_pylist() == list(range(table.num_rows))
    feat = np.array(table.column("feature").to_pylist(), dtype=np.float64)
    for cell, r in ref.items():
        i = rows[cell]
        assert table.column("num_views")[i].as_py() == r["views"]
        np.testing.assert_allclose(feat[i], r["feature"], atol=1e-3)
        assert table.column("weight")[i].as_py() == pytest.approx(r["weight"], rel=1e-5)
        assert table.column("entropy")[i].as_py() == pytest.approx(r["entropy"], rel=1e-3, abs=1e-5)
        for name in ("stderr", "pwkl"):
            got = table.column(name)[i].as_py()
            if math.isinf(r[name]):
                assert got == math.inf  # the +inf rule for one-view cells
            else:
                assert got == pytest.approx(r[name], rel=1e-4, abs=1e-6)
    assert (table.column("num_views").to_numpy() == 1).any()
    assert (table.column("num_views").to_numpy() >= 3).any()


def test_grid_layers_and_readers(tmp_path: Path) -> None:
    store = grid_store(tmp_path / "s")
    path = build_grid(store, GridConfig(cell_size=0.1))
    df = pl.read_parquet(path)
    assert {"x", "y", "z_max", "obstacle", "r", "g", "b"} <= set(df.columns)
    # the box top (0.5 m) is an obstacle, the floor is not
    assert df.filter(pl.col("z_max") > 0.4)["obstacle"].all()
    assert not df.filter(pl.col("z_max") < 0.05)["obstacle"].any()
    assert df["z_max"].max() == pytest.approx(0.5, abs=2e-3)
    ((n, views),) = duckdb.sql(f"select count(*), sum(num_views) from '{path}'").fetchall()
    ((samples,),) = duckdb.sql(f"select count(*) from '{store / 'cell_views.parquet'}'").fetchall()
    assert n == df.height
    assert views == samples
    layout = GridLayout.from_table(read_table(path))
    rgb = np.asarray(Image.open(store / "grid_rgb.png"))
    assert rgb.shape == (layout.shape[1], layout.shape[0], 3)
    # the image pixel of a cell is its top colour; north is up
    row = df.row(0, named=True)
    assert tuple(rgb[layout.shape[1] - 1 - row["iy"], row["ix"]]) == (row["r"], row["g"], row["b"])
    np.testing.assert_array_equal(
        grid_image(np.array([0]), np.array([0]), np.array([7.0]), (2, 3))[2], [7.0, np.nan]
    )


def test_cell_views_read_as_numbers_by_polars_and_duckdb(tmp_path: Path) -> None:
    """The (view, cell) samples, without feature copies: the declared columns, read as the
    same numbers by polars and duckdb (which no one here wrote) as by pyarrow, and adding
    up to the cells' weights and pixel counts."""
    store = grid_store(tmp_path / "s")
    cells = read_table(build_grid(store, GridConfig(cell_size=0.1)))
    path = store / "cell_views.parquet"
    table = pq.read_table(path)
    assert table.schema.equals(pa.schema(CELL_VIEWS_FIELDS))  # no feature column
    df = pl.read_parquet(path)
    assert df.columns == ["cell_id", "view_id", "weight", "num_pixels"]
    for name in df.columns:
        np.testing.assert_array_equal(df[name].to_numpy(), table.column(name).to_numpy())
    got = duckdb.sql(f"select cell_id, view_id, weight, num_pixels from '{path}'").fetchnumpy()
    for name in df.columns:
        np.testing.assert_array_equal(got[name], table.column(name).to_numpy())
    # one row per (view, cell): each cell's samples sum to its weight and pixel count
    per_cell = duckdb.sql(
        f"select cell_id, count(*) n, sum(weight) w, sum(num_pixels) p from '{path}' "
        "group by cell_id order by cell_id"
    ).fetchnumpy()
    np.testing.assert_array_equal(per_cell["cell_id"], np.arange(cells.num_rows))
    np.testing.assert_array_equal(per_cell["n"], cells.column("num_views").to_numpy())
    np.testing.assert_array_equal(per_cell["p"], cells.column("num_pixels").to_numpy())
    np.testing.assert_allclose(per_cell["w"], cells.column("weight").to_numpy(), rtol=1e-5)
    assert not df.select(["cell_id", "view_id"]).is_duplicated().any()


def test_cell_views_row_groups_do_not_change_the_rows(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Row groups smaller than a view's samples (a view split across groups): the same
    rows as one group holds."""
    whole = grid_store(tmp_path / "whole")
    build_grid(whole, GridConfig(cell_size=0.1))
    monkeypatch.setattr(grid_module, "VIEWS_GROUP_ROWS", 7)
    small = grid_store(tmp_path / "small")
    build_grid(small, GridConfig(cell_size=0.1))
    one, many = (pq.ParquetFile(s / "cell_views.parquet") for s in (whole, small))
    assert one.num_row_groups == 1
    assert many.num_row_groups == -(-many.metadata.num_rows // 7) > 3
    assert many.read().equals(one.read())


def test_grid_of_an_older_layout_is_rebuilt(tmp_path: Path) -> None:
    """A grid whose cell_views still carries a feature copy (the older layout) is not
    current: `care fuse grid` rebuilds it without --overwrite, to the declared layout."""
    store = grid_store(tmp_path / "s")
    path = build_grid(store, GridConfig(cell_size=0.1))
    views = store / "cell_views.parquet"
    table = pq.read_table(views)
    feature = pa.FixedSizeListArray.from_arrays(
        pa.array(np.zeros(table.num_rows * GRID_DIM, np.float16)), GRID_DIM
    )
    old = table.append_column("feature", feature).replace_schema_metadata(table.schema.metadata)
    pq.write_table(old, views)
    from care_maps.core.outputs import record_table

    record_table(views)  # whole, as the older program recorded it
    stamp = path.stat().st_mtime_ns
    build_grid(store, GridConfig(cell_size=0.1))
    assert path.stat().st_mtime_ns != stamp
    assert pq.read_schema(views).names == [f.name for f in CELL_VIEWS_FIELDS]


@pytest.mark.parametrize("cells_per_pass", [7, 50])
def test_bounded_memory_passes_give_the_same_map(tmp_path: Path, cells_per_pass: int) -> None:
    """Fused a few cells per pass (views read again for each later pass), the map equals the
    one-pass map: same rows, same values up to float32 rounding, same cell_views bytes."""
    whole = grid_store(tmp_path / "whole", n=5)
    one = pq.read_table(build_grid(whole, GridConfig(cell_size=0.1, stride=1)))
    part = grid_store(tmp_path / "part", n=5)
    config = GridConfig(cell_size=0.1, stride=1)
    passes = pq.read_table(build_grid(part, config, run=Execution(cells_per_pass=cells_per_pass)))
    assert one.num_rows > 3 * cells_per_pass  # really several passes
    assert passes.schema.equals(one.schema)
    md_one, md_passes = dict(one.schema.metadata), dict(passes.schema.metadata)
    for md in (md_one, md_passes):
        md.pop(b"care.store.created")  # two stores, two creation times
    assert md_passes == md_one
    for name in one.column_names:
        a, b = one.column(name).to_pylist(), passes.column(name).to_pylist()
        if name in ("log_norm", "entropy", "stderr", "pwkl", "top_probs"):
            np.testing.assert_allclose(
                np.asarray(b, np.float64), np.asarray(a, np.float64), rtol=1e-6, err_msg=name
            )
        else:
            assert a == b, name
    views = (whole / "cell_views.parquet").read_bytes()
    assert (part / "cell_views.parquet").read_bytes() == views


@pytest.mark.parametrize("cells_per_pass", [None, 7])
def test_views_prepared_ahead_give_the_same_bytes(
    tmp_path: Path, cells_per_pass: int | None
) -> None:
    """Decoding and sampling views on background threads (the default) or all in one thread,
    in one pass or in several: the same cells and cell_views bytes."""
    store = grid_store(tmp_path / "s", n=5)
    built = {}
    for ahead in (0, 1, 2):
        run = Execution(cells_per_pass=cells_per_pass, read_ahead=ahead, overwrite=True)
        cells = build_grid(store, GridConfig(cell_size=0.1, stride=1), run=run).read_bytes()
        built[ahead] = cells, (store / "cell_views.parquet").read_bytes()
    assert built[1] == built[0]
    assert built[2] == built[0]


def test_memory_budget_too_small_is_one_clear_error(tmp_path: Path) -> None:
    store = grid_store(tmp_path / "s")
    with pytest.raises(FuseError, match="memory-budget"):
        build_grid(store, GridConfig(cell_size=0.1), run=Execution(memory_budget=1 << 20))
    assert not (store / "cells.parquet").exists()
    # how memory is used is not what the map is: a budget does not force a rebuild
    path = build_grid(store, GridConfig(cell_size=0.1))
    mtime = path.stat().st_mtime_ns
    build_grid(store, GridConfig(cell_size=0.1), run=Execution(memory_budget=4 << 30))
    assert path.stat().st_mtime_ns == mtime


def test_rerun_is_skipped_and_overwrite_rebuilds(tmp_path: Path) -> None:
    store = grid_store(tmp_path / "s")
    path = build_grid(store, GridConfig(cell_size=0.1))
    stamp = path.stat().st_mtime_ns
    build_grid(store, GridConfig(cell_size=0.1))
    assert path.stat().st_mtime_ns == stamp
    build_grid(store, GridConfig(cell_size=0.1), run=Execution(overwrite=True))
    assert path.stat().st_mtime_ns != stamp
    build_grid(store, GridConfig(cell_size=0.2))  # another config rebuilds
    assert GridLayout.from_table(read_table(path)).cell_size == 0.2


def test_interrupted_build_keeps_previous_grid(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    store = grid_store(tmp_path / "s")
    path = build_grid(store, GridConfig(cell_size=0.1))
    before = path.read_bytes(), (store / "cell_views.parquet").read_bytes()
    real = grid_module.view_samples
    calls = []

    def failing(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise FuseError("disk on fire")
        return real(*args, **kwargs)

    monkeypatch.setattr(grid_module, "view_samples", failing)
    with pytest.raises(FuseError, match="disk on fire"):
        build_grid(store, GridConfig(cell_size=0.2))
    assert (path.read_bytes(), (store / "cell_views.parquet").read_bytes()) == before
    assert not [p for p in store.iterdir() if p.name.startswith(".")]


@pytest.mark.parametrize("cells_per_pass", [None, 7])
def test_recompute_equals_fresh_build(tmp_path: Path, cells_per_pass: int | None) -> None:
    """Another vocabulary and logit scale: the recompute streams the store's views through
    the build's per-view code (in one pass, or several), so its columns are a fresh
    build's with those settings bit for bit."""
    config = GridConfig(cell_size=0.1, stride=1, distance_weighting=False, z_min=0.2)
    store = grid_store(tmp_path / "s", n=5)
    build_grid(store, config)
    views = (store / "cell_views.parquet").read_bytes()
    vocab = ("lamp", "chair", "bed")
    recomputed = read_table(
        recompute_grid(store, vocab, logit_scale=30.0, run=Execution(cells_per_pass=cells_per_pass))
    )
    fresh_store = grid_store(tmp_path / "t", n=5)
    fresh = read_table(build_grid(fresh_store, replace(config, vocabulary=vocab, logit_scale=30.0)))
    assert recomputed.num_rows > 3 * 7
    assert recomputed.schema.equals(fresh.schema)  # metadata aside
    for name in fresh.column_names:
        assert recomputed.column(name).equals(fresh.column(name)), name
    md = pq.read_schema(store / "cells.parquet").metadata
    assert md[b"care.vocabulary"] == b'["lamp", "chair", "bed"]'
    assert float(md[b"care.logit_scale"]) == 30.0
    # the query sidecar is written again: current for the new columns, a fresh build's arrays
    sidecar = read_sidecar(store / "cells.parquet", md)
    assert sidecar is not None
    fresh_sidecar = read_sidecar(
        fresh_store / "cells.parquet", pq.read_schema(fresh_store / "cells.parquet").metadata
    )
    assert fresh_sidecar is not None
    for name, values in fresh_sidecar.items():
        assert sidecar[name].dtype == values.dtype, name
        assert np.array_equal(sidecar[name], values), name
    assert (store / "cell_views.parquet").read_bytes() == views  # the samples did not change
    # back to the store's vocabulary and scale: the first build's columns again
    first = read_table(build_grid(fresh_store, config))
    again = read_table(recompute_grid(store, list(GRID_NAMES), logit_scale=config.logit_scale))
    for name in first.column_names:
        assert again.column(name).equals(first.column(name)), name


def test_recompute_whose_sidecar_cannot_be_written_leaves_a_whole_map(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The disk fills while the query sidecar is written again: the error comes out, the
    rewritten table stands whole with no sidecar (queries decode the table) and nothing
    half-written is left; a re-run writes it."""
    from care_maps.fuse import sidecar as sidecar_module
    from care_maps.query.map import load_map

    store = grid_store(tmp_path / "s", n=5)
    build_grid(store, GridConfig(cell_size=0.1, stride=1))
    real = sidecar_module.SidecarWriter.write

    def full(self, chunk):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(sidecar_module.SidecarWriter, "write", full)
    with pytest.raises(OSError, match="No space left"):
        recompute_grid(store, logit_scale=30.0)
    md = pq.read_schema(store / "cells.parquet").metadata
    assert float(md[b"care.logit_scale"]) == 30.0  # the table was rewritten, whole
    assert read_sidecar(store / "cells.parquet", md) is None
    assert not [p for p in store.iterdir() if p.name.startswith(".")]  # no temp folder
    assert load_map(store, "grid").num_candidates > 0  # read from the table
    monkeypatch.setattr(sidecar_module.SidecarWriter, "write", real)
    recompute_grid(store, logit_scale=30.0)
    assert read_sidecar(store / "cells.parquet", md) is not None


def test_recompute_needs_the_store_it_was_built_from(tmp_path: Path) -> None:
    """The per-view features come from the store: a grid moved onto other views (or a
    store ingested again) is refused in one line, the map left as it was."""
    store = grid_store(tmp_path / "s")
    build_grid(store, GridConfig(cell_size=0.1))
    other = grid_store(tmp_path / "t", seed=1)
    build_grid(other, GridConfig(cell_size=0.1))
    for name in ("cells.parquet", "cell_views.parquet"):
        (other / name).write_bytes((store / name).read_bytes())
    from care_maps.core.outputs import record_table

    record_table(other / "cells.parquet")
    record_table(other / "cell_views.parquet")
    before = (other / "cells.parquet").read_bytes()
    with pytest.raises(FuseError, match=r"built from another version of the store"):
        recompute_grid(other, ["lamp", "bed"])
    assert (other / "cells.parquet").read_bytes() == before


def test_views_without_feature_rows_are_one_clear_error(tmp_path: Path) -> None:
    """Four views but two feature maps: out of step, not a two-view map."""
    path = tmp_path / "s"
    with StoreWriter(path, EncoderInfo("test", "1", GRID_DIM, GRID_NAMES)) as writer:
        for i, (frame, feats) in enumerate(grid_frames(4)):
            writer.add(frame, feats if i < 2 else None)
        writer.set_text(GRID_NAMES, grid_text())
        writer.commit({"source": "synthetic"})
    with pytest.raises(FuseError, match="out of step"):
        build_grid(path, GridConfig())
    assert not (path / "cells.parquet").exists()


def test_bad_inputs_raise_one_clear_error(tmp_path: Path) -> None:
    store = grid_store(tmp_path / "s")
    with pytest.raises(FuseError, match="no depth pixel"):
        build_grid(store, GridConfig(z_min=5.0, z_max=6.0))
    with pytest.raises(FuseError, match="invalid grid config"):
        GridConfig(cell_size=0.0)
    with pytest.raises(FuseError, match="cannot embed"):
        build_grid(store, GridConfig(vocabulary=("unicorn",)))


def test_rerun_layers_and_blueprint(tmp_path: Path) -> None:
    from rerun.chunk import RrdReader

    from care_maps.core.store import Store
    from care_maps.core.viz import rrd_entity_counts
    from care_maps.fuse.grid import grid_image
    from care_maps.fuse.viz_grid import (
        GRID_CELLS_3D,
        MEASURE_LAYERS,
        confidence_layer,
        default_class,
        log_grid,
        map_blueprint,
        measure_layers,
    )

    store = grid_store(tmp_path / "s")
    rrd = tmp_path / "grid.rrd"
    cells = read_table(build_grid(store, GridConfig(cell_size=0.1)))
    log_grid(store, rrd)
    target = default_class(cells)
    assert target in GRID_NAMES
    counts = rrd_entity_counts(rrd)
    assert counts[("/grid/rgb/value", "Image:buffer")] == 1
    layers = [confidence_layer(target), *MEASURE_LAYERS[1:]]
    for name in layers:  # real values (hover shows them), with an overlay of their status
        assert counts[(f"/grid/{name}/value", "DepthImage:buffer")] == 1
        assert counts[(f"/grid/{name}/status", "SegmentationImage:buffer")] == 1
    assert counts[(f"/{GRID_CELLS_3D}", "Points3D:positions")] == 1
    assert RrdReader(rrd).blueprints()
    # the stderr layer read back is the cells' stderr column, cell for cell; NaN off the map
    chunks = [c for c in RrdReader(rrd).stream() if str(c.entity_path) == "/grid/stderr/value"]
    batch = chunks[0].to_record_batch()
    buffer = np.asarray(batch.column("DepthImage:buffer").to_pylist()[0][0], np.uint8)
    layout = GridLayout.from_table(cells)
    logged = np.frombuffer(buffer.tobytes(), np.float32).reshape(layout.shape[1], layout.shape[0])
    ix, iy = cells.column("ix").to_numpy(), cells.column("iy").to_numpy()
    expected = grid_image(ix, iy, cells.column("stderr").to_numpy(), layout.shape)
    finite = np.isfinite(expected)
    np.testing.assert_allclose(logged[finite], expected[finite], rtol=1e-6)
    assert np.isnan(logged[~finite]).all()
    # +inf (a single view) and unobserved are told apart by the status overlay
    chunks = [c for c in RrdReader(rrd).stream() if str(c.entity_path) == "/grid/stderr/status"]
    buffer = chunks[0].to_record_batch().column("SegmentationImage:buffer").to_pylist()[0][0]
    status = np.asarray(buffer, np.uint8).reshape(logged.shape)
    assert np.isposinf(expected).any()
    np.testing.assert_array_equal(status == 2, np.isposinf(expected))
    np.testing.assert_array_equal(status == 1, np.isnan(expected))
    # several classes (the evaluation's query classes): a layer each, values P_c[class]
    many = tmp_path / "many.rrd"
    log_grid(store, many, target=["chair", "sofa"])
    counts = rrd_entity_counts(many)
    for name in ("chair", "sofa"):
        assert counts[(f"/grid/{confidence_layer(name)}/value", "DepthImage:buffer")] == 1
    # the confidence layers of all classes sum to one on occupied cells, NaN elsewhere
    total = sum(measure_layers(Store(store), cells, name)["confidence"] for name in GRID_NAMES)
    occupied = np.isfinite(total)
    assert occupied.sum() == cells.num_rows
    np.testing.assert_allclose(total[occupied], 1.0, rtol=1e-4)
    assert map_blueprint(views_3d=[]) is not None


@pytest.mark.slow
def test_cli_grid_and_recompute(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from care_maps.cli.main import _register, app

    _register()
    store = grid_store(tmp_path / "s")
    runner = CliRunner()
    result = runner.invoke(app, ["fuse", "grid", str(store), "--cell-size", "0.1", "--stride", "2"])
    assert result.exit_code == 0, result.output
    assert "candidates" in result.output
    result = runner.invoke(
        app, ["fuse", "grid", str(store), "--recompute", "--vocabulary", "bed,sofa"]
    )
    assert result.exit_code == 0, result.output
    md = pq.read_schema(store / "cells.parquet").metadata
    assert md[b"care.vocabulary"] == b'["bed", "sofa"]'
    assert json.loads(md[b"care.grid.config_json"])["stride"] == 2
    assert runner.invoke(app, ["fuse", "grid", "--help"]).exit_code == 0
    assert runner.invoke(app, ["fuse", "instances", "--help"]).exit_code == 0
    bad = runner.invoke(app, ["fuse", "instances", str(store), "--set", "no_such_field=1"])
    assert isinstance(bad.exception, FuseError)
    assert "no_such_field" in str(bad.exception)
    args = ["fuse", "grid", str(store), "--cell-size", "0.1", "--memory-budget"]
    assert runner.invoke(app, [*args, "6G"]).exit_code == 0
    bad = runner.invoke(app, [*args, "lots"])
    assert isinstance(bad.exception, FuseError)
    assert "--memory-budget" in str(bad.exception)


@pytest.mark.slow
def test_sample_world_recording(tmp_path: Path) -> None:
    """A real sample-world recording, ingested with the labels encoder: the streaming grid
    equals the per-pixel reference, and cells carry the class of the object they show."""
    from care_maps.core.encoders import EncoderOptions, make_encoder
    from care_maps.core.store import Store
    from care_maps.ingest.pipeline import IngestConfig, run_ingest
    from care_maps.truth.formats.native import read_native
    from care_maps.world.record import make_recording
    from care_maps.world.render import RenderConfig
    from care_maps.world.scene import SceneConfig

    recording = tmp_path / "tiny.mcap"
    make_recording(
        recording, SceneConfig(seed=3, num_rooms=1), RenderConfig(width=96, height=72), frames=12
    )
    encoder = make_encoder("labels", EncoderOptions(perception="ideal"))
    store_path = run_ingest(
        recording,
        tmp_path / "store",
        IngestConfig(),
        run=Execution(progress=False),
        encoder=encoder,
    )
    cfg = GridConfig(stride=3, logit_scale=100.0)
    table = read_table(build_grid(store_path, cfg))
    store = Store(store_path)
    frames = [
        (frame, feats)
        for (_, frame), (_, feats) in zip(
            store.iter_frames(extras=False), store.iter_features(), strict=True
        )
    ]
    ref = _reference(frames, cfg, store.text_embeddings()[1].astype(np.float64))
    rows = _by_cell(table)
    assert set(rows) == set(ref)
    feat = np.array(table.column("feature").to_pylist(), dtype=np.float64)
    for cell, r in ref.items():
        i = rows[cell]
        assert table.column("num_views")[i].as_py() == r["views"]
        np.testing.assert_allclose(feat[i], r["feature"], atol=2e-3)
        for name in ("stderr", "pwkl"):
            want, got = r[name], table.column(name)[i].as_py()
            assert (
                got == pytest.approx(want, rel=1e-3, abs=1e-5)
                if math.isfinite(want)
                else got == math.inf
            )
    # the top class of a cell is the class of the ground-truth object at its highest point
    gt = read_native(recording)
    xyz = np.stack([table.column(c).to_numpy() for c in ("x", "y", "z_max")], axis=1)
    inst = gt.label_points(xyz, max_dist=0.06)
    on_object = inst > 0
    assert on_object.sum() > 20
    class_of = dict(
        zip(gt.instance_ids.tolist(), gt.instances.column("class_name").to_pylist(), strict=True)
    )
    vocabulary = json.loads(table.schema.metadata[b"care.vocabulary"])
    top = [vocabulary[c[0]] for c in table.column("top_classes").to_pylist()]
    agree = np.mean([top[i] == class_of[inst[i]] for i in np.flatnonzero(on_object)])
    assert agree > 0.7
