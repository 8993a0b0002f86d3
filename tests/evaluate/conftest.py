"""Small fused scenes written by hand with the map-table contract, with real ground truth.

Each scene has two rooms (x < 5 and x >= 5), six objects as point clusters, a scene point
cloud equal to the GT points (so labels are exact), instance masks (one per object, plus a
half-overlapping and a mixed mask) and a 0.5 m grid, with features that mix the true class
with a confuser so that first attempts fail often enough to replan.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from care_maps.core.store import META_VERSION, TEXT_SCHEMA, write_table_atomic
from care_maps.fuse.measures import candidate_columns, candidate_metadata
from care_maps.truth.formats.native import write_native
from care_maps.truth.model import GroundTruth, Room, instances_table

VOCAB = ["chair", "table", "sofa", "lamp", "bed"]
OBJECTS = [  # (class, room, centre xy)
    ("chair", 0, (1.0, 1.0)),
    ("chair", 0, (3.0, 2.0)),
    ("table", 0, (2.0, 4.0)),
    ("sofa", 1, (7.0, 1.0)),
    ("chair", 1, (8.0, 3.0)),
    ("lamp", 1, (6.0, 4.0)),
]


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _features(rng, text, classes, strength):
    """Features near each class's text embedding, pulled towards a random confuser."""
    confuser = rng.integers(0, len(VOCAB), size=len(classes))
    mix = (
        text[classes]
        + strength * text[confuser]
        + 0.3 * rng.normal(size=(len(classes), text.shape[1]))
    )
    return _unit(mix)


def make_scene(root: Path, name: str, seed: int) -> tuple[Path, Path]:
    """Write ``root/<name>.mcap`` ground truth and the store ``root/stores/<name>``."""
    rng = np.random.default_rng(seed)
    d = 16
    text = _unit(rng.normal(size=(len(VOCAB), d))).astype(np.float32)
    # ground truth: 40 points per object in a 0.4 m cube, plus floor points (structure)
    pts, inst = [], []
    for i, (_, _, (x, y)) in enumerate(OBJECTS, start=1):
        pts.append(np.array([x, y, 0.4]) + rng.uniform(-0.2, 0.2, size=(40, 3)))
        inst.append(np.full(40, i))
    pts.append(np.c_[rng.uniform(0, 10, (200, 2)), np.zeros(200)])
    inst.append(np.zeros(200))
    points = np.concatenate(pts).astype(np.float32)
    point_instance = np.concatenate(inst).astype(np.int32)
    rows = []
    for i, (cls, room, (x, y)) in enumerate(OBJECTS, start=1):
        rows.append(
            {
                "instance_id": i, "class_name": cls, "class_id": VOCAB.index(cls) + 1,
                "room_id": room, "bbox_min": [x - 0.2, y - 0.2, 0.2], "bbox_max": [x + 0.2, y + 0.2, 0.6],
            }
        )  # fmt: skip
    rooms = [
        Room(0, "living", np.array([[0, 0], [5, 0], [5, 5], [0, 5]], float)),
        Room(1, "bedroom", np.array([[5, 0], [10, 0], [10, 5], [5, 5]], float)),
    ]
    gt = GroundTruth(("void", *VOCAB), instances_table(rows), rooms, points, point_instance)
    recording = root / f"{name}.mcap"
    recording.write_bytes(b"")
    write_native(gt, recording)

    store = root / "stores" / name
    store.mkdir(parents=True)
    # scene points = GT points; instance masks over them
    masks, classes, centres = [], [], []
    for i, (cls, _, (x, y)) in enumerate(OBJECTS, start=1):
        masks.append(np.flatnonzero(point_instance == i))
        classes.append(VOCAB.index(cls))
        centres.append([x, y, 0.4])
    half = np.concatenate(
        [np.flatnonzero(point_instance == 1)[:20], np.flatnonzero(point_instance == 0)[:60]]
    )
    masks.append(half)  # IoU with object 1: 20 / (80 + 40 - 20) = 0.2, a miss
    classes.append(0)
    centres.append([1.2, 1.2, 0.3])
    masks.append(np.flatnonzero((point_instance == 4) | (point_instance == 6)))  # IoU 0.5 with each
    classes.append(2)
    centres.append([6.5, 2.5, 0.4])
    n_inst = len(masks)
    feats = _features(rng, text, np.array(classes), strength=1.2)
    views = rng.integers(1, 6, size=n_inst)
    table = candidate_columns(
        feats, text, 20.0, num_views=views,
        stderr=np.where(views >= 2, rng.random(n_inst), np.inf),
        pwkl=np.where(views >= 2, rng.random(n_inst), np.inf),
    )  # fmt: skip
    table = table.append_column("num_points", pa.array([len(m) for m in masks], pa.int32()))
    table = table.append_column(
        "point_indices", pa.array([m.astype(np.int32) for m in masks], pa.list_(pa.int32()))
    )
    table = table.append_column("center", pa.array(centres, pa.list_(pa.float32())))
    meta = candidate_metadata(VOCAB, 20.0, "test")
    write_table_atomic(table, store / "instances.parquet", meta)
    # grid: 0.5 m cells; the class of the nearest object within 1.5 m, else a random class
    gx, gy = np.meshgrid(np.arange(0.25, 10, 0.5), np.arange(0.25, 5, 0.5))
    xy = np.c_[gx.ravel(), gy.ravel()]
    centres_xy = np.array([c for _, _, c in OBJECTS])
    dist = np.linalg.norm(xy[:, None] - centres_xy[None], axis=-1)
    near = dist.argmin(1)
    cell_cls = np.where(
        dist.min(1) < 1.5,
        [VOCAB.index(OBJECTS[j][0]) for j in near],
        rng.integers(0, len(VOCAB), len(xy)),
    )
    n_cell = len(xy)
    cviews = rng.integers(1, 8, size=n_cell)
    cells = candidate_columns(
        _features(rng, text, cell_cls, strength=1.0), text, 20.0, num_views=cviews,
        stderr=np.where(cviews >= 2, rng.random(n_cell), np.inf),
        pwkl=np.where(cviews >= 2, rng.random(n_cell), np.inf),
    )  # fmt: skip
    for col, values in (("x", xy[:, 0]), ("y", xy[:, 1]), ("z_max", np.full(n_cell, 0.6))):
        cells = cells.append_column(col, pa.array(values.astype(np.float32)))
    grid_md = {**meta, b"care.grid.cell_size": b"0.5"}
    write_table_atomic(cells, store / "cells.parquet", grid_md)
    sp = pa.table({c: pa.array(points[:, i]) for i, c in enumerate("xyz")})
    write_table_atomic(sp, store / "scene_points.parquet")
    write_table_atomic(
        pa.table({"name": VOCAB, "embedding": list(text)}, schema=TEXT_SCHEMA),
        store / "text.parquet",
    )
    meta_json = {
        "meta_version": META_VERSION,
        "schema_version": 1,
        "num_views": 0,
        "source": {"path": str(recording.resolve())},
    }
    (store / "meta.json").write_text(json.dumps(meta_json))
    return recording, store


@pytest.fixture
def dataset(tmp_path: Path) -> Path:
    """A 3-scene dataset directory with ``index.json``."""
    root = tmp_path / "dataset"
    root.mkdir()
    names = [f"scene_{i}" for i in range(3)]
    for i, name in enumerate(names):
        make_scene(root, name, seed=i)
    (root / "index.json").write_text(json.dumps({"recordings": [f"{n}.mcap" for n in names]}))
    return root


@pytest.fixture(scope="session")
def ray_session():
    """One local Ray for the whole test session (starting one costs seconds)."""
    ray = pytest.importorskip("ray")
    if not ray.is_initialized():
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()
