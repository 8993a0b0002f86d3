"""The ROS occupancy map of a fused grid, read back the way ``nav2_map_server`` reads it.

The reader below follows nav2's ``map_io`` (``loadMapFromFile``) as documented: the YAML's
``image`` relative to the YAML, P5 greyscale, occupancy ``(255 - v) / 255`` with
``negate: 0``, trinary thresholds, and image row ``y`` stored as map row ``height - 1 - y``
(the origin is the lower-left pixel). It parses the PGM itself, not with PIL.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import polars as pl
import pytest
import yaml

from care_maps.core.frames import Frame
from care_maps.core.store import EncoderInfo, StoreWriter
from care_maps.fuse.grid import GridConfig, build_grid
from care_maps.fuse.rosmap import FREE, OCCUPIED, UNKNOWN, occupancy_image, write_ros_map

H, W, D = 24, 32, 4
K = np.array([[20.0, 0, 15.5], [0, 20.0, 11.5], [0, 0, 1]])


def _read_pgm(path: Path) -> np.ndarray:
    data = path.read_bytes()
    tokens, pos = [], 0
    while len(tokens) < 4:  # magic, width, height, maxval, separated by whitespace
        while data[pos : pos + 1].isspace():
            pos += 1
        end = pos
        while not data[end : end + 1].isspace():
            end += 1
        tokens.append(data[pos:end].decode())
        pos = end
    assert tokens[0] == "P5"
    width, height, maxval = map(int, tokens[1:])
    assert maxval == 255
    return np.frombuffer(data[pos + 1 :], np.uint8, width * height).reshape(height, width)


def nav2_load(yaml_path: Path) -> tuple[np.ndarray, float, tuple[float, float]]:
    """(height, width) int8 OccupancyGrid data in message order (row 0 = bottom), the
    resolution and the origin (x, y): nav2_map_server's trinary reading."""
    spec = yaml.safe_load(yaml_path.read_text())
    assert spec["mode"] == "trinary"
    assert spec["negate"] == 0
    image = _read_pgm(yaml_path.parent / spec["image"]).astype(np.float64)
    occ = (255.0 - image) / 255.0
    grid = np.full(image.shape, -1, np.int8)
    grid[occ > spec["occupied_thresh"]] = 100
    grid[occ < spec["free_thresh"]] = 0
    return grid[::-1], float(spec["resolution"]), tuple(spec["origin"][:2])


def _store(path: Path) -> Path:
    """A floor with two boxes (0.5 m and 0.05 m tall), seen from above by three cameras."""
    rng = np.random.default_rng(3)
    with StoreWriter(path, EncoderInfo("test", "1", D, ("chair", "table"))) as writer:
        for i in range(3):
            height = 2.0
            depth = np.full((H, W), height, np.float32)
            depth[4:10, 5:12] = height - 0.5  # an obstacle
            depth[14:20, 20:26] = height - 0.05  # a rug: below obstacle_height, free
            pose = np.eye(4)
            pose[:3, :3] = np.diag([1.0, -1.0, -1.0])
            pose[:3, 3] = [0.3 + 0.05 * i, -0.2, height]
            rgb = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
            feats = rng.normal(size=(2, 2, D)).astype(np.float32)
            feats /= np.linalg.norm(feats, axis=-1, keepdims=True)
            writer.add(Frame(10**9 + i * 10**8, rgb, depth, K, pose), feats)
        writer.set_text(("chair", "table"), np.eye(2, D, dtype=np.float32))
        writer.commit({"source": "synthetic", "world_frame": "odom"})
    return path


def test_occupancy_map_lands_obstacles_where_the_grid_has_them(tmp_path: Path) -> None:
    store = _store(tmp_path / "s")
    cells = pl.read_parquet(build_grid(store, GridConfig(cell_size=0.05)))
    grid, resolution, origin = nav2_load(store / "map.yaml")
    assert resolution == pytest.approx(0.05)
    rows, cols = np.nonzero(grid >= 0)
    # map cell (col, row) centre in the map frame, as nav2 places it
    centres = np.stack(
        [origin[0] + (cols + 0.5) * resolution, origin[1] + (rows + 0.5) * resolution], 1
    )
    known = {
        tuple(np.round(c, 4)): int(grid[r, q]) for c, r, q in zip(centres, rows, cols, strict=True)
    }
    expected = {
        (round(x, 4), round(y, 4)): 100 if obstacle else 0
        for x, y, obstacle in cells.select("x", "y", "obstacle").iter_rows()
    }
    assert known == expected  # every seen cell, in the right place and class; no others
    assert 0 < sum(v == 100 for v in known.values()) < len(known)
    assert (grid == -1).any() or len(known) == grid.size


def test_trinary_levels_and_yaml_fields(tmp_path: Path) -> None:
    image = occupancy_image(
        np.array([0, 1, 2]), np.array([0, 0, 1]), np.array([True, False, True]), (3, 2)
    )
    assert image.tolist() == [[UNKNOWN, UNKNOWN, OCCUPIED], [OCCUPIED, FREE, UNKNOWN]]
    pgm, spec = write_ros_map(image, 0.1, (-2.5, 4.0), tmp_path)
    fields = yaml.safe_load(spec.read_text())
    assert fields["image"] == pgm.name
    assert fields["origin"] == [-2.5, 4.0, 0.0]
    grid, _, _ = nav2_load(spec)
    assert grid.tolist() == [[100, 0, -1], [-1, -1, 100]]  # row 0 is the bottom (y = 4.0)


@pytest.mark.slow
def test_cli_query_and_replan_return_goal_poses(tmp_path: Path) -> None:
    store = _store(tmp_path / "s")
    build_grid(store, GridConfig(cell_size=0.05))
    run = [sys.executable, "-m", "care_maps.cli.main"]
    q = subprocess.run(
        [*run, "query", str(store), "chair", "--map", "grid", "--top", "2", "--json"],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    rows = json.loads(q.stdout)["candidates"]
    header = rows[0]["goal"]["pose_stamped"]["header"]
    assert header["frame_id"] == "odom"
    assert header["stamp"] == {"sec": 1, "nanosec": 200_000_000}  # the last view's stamp
    x, y = rows[0]["position"][:2]
    r = subprocess.run(
        [*run, "replan", str(store), "chair", "--map", "grid", "--visited", f"{x},{y}"],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    out = json.loads(r.stdout)
    assert out["strategy"] in {"min_stderr", "max_confidence"}
    assert np.hypot(out["position"][0] - x, out["position"][1] - y) > 1.0  # excluded around it
    # the nearest of the same top-k set, by the distances along free space from the start
    near = subprocess.run(
        [*run, "replan", str(store), "chair", "--map", "grid", "--visited", f"{x},{y}",
         "--strategy", "nearest_topk"],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    nearest = json.loads(near.stdout)
    assert nearest["strategy"] == "nearest_topk"
    if out["strategy"] == "min_stderr" and out["distance"] is not None:
        assert nearest["distance"] <= out["distance"] + 1e-9
    bad = subprocess.run(
        [*run, "replan", str(store), "chair", "--visited", "1,2,3"], capture_output=True, text=True
    )
    assert bad.returncode == 1
    assert bad.stderr.count("\n") == 1
    assert "--visited" in bad.stderr


@pytest.mark.slow
def test_cli_batch_writes_one_table(tmp_path: Path) -> None:
    import polars as pl

    store = _store(tmp_path / "s")
    build_grid(store, GridConfig(cell_size=0.05))
    queries = tmp_path / "q.csv"
    queries.write_text('query,visited\nchair,\ntable,"0.3,-0.2"\nchair,\n')
    run = [sys.executable, "-m", "care_maps.cli.main", "query", str(store), "--map", "grid"]
    done = subprocess.run(
        [*run, "--batch", str(queries), "-k", "2"], capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "ms a query" in done.stdout
    table = pl.read_parquet(tmp_path / "q.answers.parquet")
    assert set(table["query_index"]) == {0, 1, 2}
    assert {"ranking", "min_stderr", "max_confidence"} <= set(table["strategy"])
    first = table.filter((pl.col("strategy") == "ranking") & (pl.col("attempt") == 1))
    assert first["goal_approach"].to_list() == [True] * 3
    neither = subprocess.run(run, capture_output=True, text=True)
    assert neither.returncode == 1
    assert "--batch" in neither.stderr
