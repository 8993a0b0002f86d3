"""Scene generator: determinism, no intersections, resting contacts, catalogue names."""

from __future__ import annotations

import csv
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from care_maps.core.errors import WorldError
from care_maps.truth.formats.native import write_native
from care_maps.world.catalogue import CATALOGUE, CLASS_NAMES, ROOM_TYPES
from care_maps.world.meshes import part_mesh
from care_maps.world.scene import SceneConfig, generate_scene

SEEDS = (0, 1, 2, 3)


def _part_boxes_from_meshes(parts) -> np.ndarray:
    """(K, 2, 3) bounds of each part, from its triangle mesh's vertices."""
    out = []
    for p in parts:
        v, _ = part_mesh(p)
        out.append([v.min(0), v.max(0)])
    return np.asarray(out)


def _interpenetrating(a: np.ndarray, b: np.ndarray, tol: float = 1e-6) -> np.ndarray:
    """(Ka, Kb) True where boxes overlap with positive volume (touching is allowed)."""
    lo = np.maximum(a[:, None, 0], b[None, :, 0])
    hi = np.minimum(a[:, None, 1], b[None, :, 1])
    return np.all(hi - lo > tol, axis=-1)


def test_same_seed_same_bytes_of_ground_truth(tmp_path: Path) -> None:
    config = SceneConfig(seed=5, num_rooms=2)
    for name in ("a", "b"):
        write_native(generate_scene(config).ground_truth(), tmp_path / f"{name}.mcap")
    for suffix in (".gt.parquet", ".gt.json"):
        assert (tmp_path / f"a{suffix}").read_bytes() == (tmp_path / f"b{suffix}").read_bytes()
    write_native(
        generate_scene(SceneConfig(seed=6, num_rooms=2)).ground_truth(), tmp_path / "c.mcap"
    )
    assert (tmp_path / "a.gt.json").read_bytes() != (tmp_path / "c.gt.json").read_bytes()


@pytest.mark.parametrize("seed", SEEDS)
def test_objects_intersect_neither_each_other_nor_walls(seed: int) -> None:
    scene = generate_scene(SceneConfig(seed=seed))
    walls = _part_boxes_from_meshes(scene.structure["wall"])
    boxes = [_part_boxes_from_meshes(o.parts) for o in scene.objects]
    for i, a in enumerate(boxes):
        assert not _interpenetrating(a, walls).any(), scene.objects[i].class_name
        for j in range(i + 1, len(boxes)):
            hit = _interpenetrating(a, boxes[j])
            assert not hit.any(), (scene.objects[i].class_name, scene.objects[j].class_name)


@pytest.mark.parametrize("seed", SEEDS)
def test_objects_rest_on_the_floor_a_support_or_a_wall(seed: int) -> None:
    scene = generate_scene(SceneConfig(seed=seed))
    by_id = {o.instance_id: o for o in scene.objects}
    for o in scene.objects:
        lo, hi = o.bbox
        placement = CATALOGUE[o.class_name].placement
        assert hi[2] < 2.6, o.class_name  # below the ceiling
        if placement in ("wall", "free"):
            assert lo[2] == pytest.approx(0.0, abs=1e-9), o.class_name
        elif placement == "on":
            support = by_id[o.support_id]
            assert support.class_name in CATALOGUE[o.class_name].supports
            assert lo[2] == pytest.approx(support.surface[4], abs=1e-9)
            # its footprint lies on the support's surface
            x0, x1, y0, y1, _ = support.surface
            assert np.all(np.array([x0, y0]) - 1e-9 <= lo[:2])
            assert np.all(hi[:2] <= np.array([x1, y1]) + 1e-9)
        else:  # hung: touches a wall's inner face
            rect = scene.room_rects[o.room_id]
            faces = np.array([rect[0] + 0.05, rect[1] + 0.05, rect[2] - 0.05, rect[3] - 0.05])
            touching = np.isclose([lo[0], lo[1], hi[0], hi[1]], faces, atol=1e-6)
            assert touching.any(), o.class_name


def test_rooms_doors_and_variety() -> None:
    counts: Counter[str] = Counter()
    for seed in range(8):
        scene = generate_scene(SceneConfig(seed=seed))
        n = len(scene.rooms)
        assert 2 <= n <= 5
        assert len(scene.doors) >= n - 1  # connected: a spanning tree at least
        counts.update(o.class_name for o in scene.objects)
    for n in (1, 6):
        assert len(generate_scene(SceneConfig(seed=0, num_rooms=n)).rooms) == n
    assert len(counts) >= 30
    assert sum(c >= 3 for c in counts.values()) >= 20  # several instances per class


def test_instances_of_a_class_vary_in_size_and_colour() -> None:
    scene = generate_scene(SceneConfig(seed=1, num_rooms=6))
    chairs = [
        o for o in scene.objects if o.class_name in ("dining chair", "kitchen cabinet", "chair")
    ]
    sizes = {tuple(np.round(o.bbox[1] - o.bbox[0], 4)) for o in chairs}
    colours = {o.parts[0].colour for o in chairs}
    assert len(sizes) > 1
    assert len(colours) > 1


def test_every_catalogue_name_is_a_matterport_raw_category(shared_data: Path) -> None:
    with (shared_data / "labels" / "matterport_category_mapping.tsv").open() as f:
        raw = {row["raw_category"] for row in csv.DictReader(f, delimiter="\t")}
    assert len(CATALOGUE) >= 30
    missing = [n for n in CLASS_NAMES if n != "void" and n not in raw]
    assert not missing
    for room in ROOM_TYPES.values():
        assert all(name in CATALOGUE for name, *_ in room.contents)


def test_bad_configuration_is_one_clear_error() -> None:
    with pytest.raises(WorldError, match="1 to 6 rooms"):
        generate_scene(SceneConfig(num_rooms=7))
    with pytest.raises(WorldError, match="room_types"):
        generate_scene(SceneConfig(num_rooms=1, room_types=("garage",)))
