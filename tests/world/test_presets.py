"""World presets: the Matterport-like catalogue and scenes, ``--preset``/``--set``, and what a
dataset records (checked against Matterport3D's own category file where it is present)."""

from __future__ import annotations

import csv
import json
from collections import Counter
from pathlib import Path

import pytest

from care_maps.core.errors import WorldError
from care_maps.world.matterport_catalogue import MATTERPORT_CATALOGUE
from care_maps.world.presets import PRESETS, WorldPreset, WorldSettings, with_sets
from care_maps.world.scene import Catalogue, SceneConfig, generate_scene

MAPPING = (
    Path(__file__).resolve().parents[2] / "../shared/data/labels/matterport_category_mapping.tsv"
)


def test_every_matterport_like_class_is_a_matterport_raw_category() -> None:
    if not MAPPING.is_file():
        pytest.skip("Matterport3D's category_mapping.tsv is not on this machine")
    with MAPPING.open() as f:
        raw = {row["raw_category"] for row in csv.DictReader(f, delimiter="\t")}
    assert len(MATTERPORT_CATALOGUE) >= 150
    assert sorted(set(MATTERPORT_CATALOGUE) - raw) == []


def test_matterport_like_scenes_hold_about_25_instances_per_room_with_siblings() -> None:
    settings = PRESETS[WorldPreset.MATTERPORT_LIKE]
    per_room, siblings, on_surfaces, total = [], 0, 0, 0
    for seed in range(3):
        scene = generate_scene(SceneConfig(seed=seed, num_rooms=2, **settings.scene_values()))
        total += len(scene.objects)
        for room in scene.rooms:
            objs = [o for o in scene.objects if o.room_id == room.room_id]
            per_room.append(len(objs))
            counts = Counter(o.class_name for o in objs)
            siblings += sum(n for n in counts.values() if n > 1)
        on_surfaces += sum(o.support_id > 0 for o in scene.objects)
        assert set(scene.class_names[4:]) == set(MATTERPORT_CATALOGUE)
    mean = sum(per_room) / len(per_room)
    assert 18 <= mean <= 32, per_room
    assert siblings / total > 0.3  # same-class siblings are common
    assert on_surfaces / total > 0.2  # small objects rest on furniture


def test_default_preset_is_the_sample_world() -> None:
    assert PRESETS[WorldPreset.DEFAULT] == WorldSettings()
    scene = generate_scene(SceneConfig(seed=4, **WorldSettings().scene_values()))
    plain = generate_scene(SceneConfig(seed=4))
    assert [(o.class_name, o.parts) for o in scene.objects] == [
        (o.class_name, o.parts) for o in plain.objects
    ]
    assert SceneConfig().catalogue is Catalogue.SAMPLE


def test_set_changes_one_knob_and_refuses_unknown_keys_and_bad_values() -> None:
    base = PRESETS[WorldPreset.MATTERPORT_LIKE]
    out = with_sets(base, ["bias_noise_scale=0.5", "instances_per_room=12", "catalogue=sample"])
    assert out.perception.bias_noise_scale == 0.5
    assert out.instances_per_room == 12
    assert out.catalogue is Catalogue.SAMPLE
    assert out.perception.view_bias_rate == base.perception.view_bias_rate
    with pytest.raises(WorldError, match="unknown knob"):
        with_sets(base, ["no_such_knob=1"])
    with pytest.raises(WorldError, match="view_bias_rate"):
        with_sets(base, ["view_bias_rate=lots"])
    with pytest.raises(WorldError, match="catalogue"):
        with_sets(base, ["catalogue=ikea"])


@pytest.mark.slow
def test_cli_bad_set_is_one_line_and_exit_2(run_cli, tmp_path: Path) -> None:
    code, _, err = run_cli("sample", "make", "--out", str(tmp_path / "d"), "--set", "nope=1")
    assert code == 2
    assert len(err.strip().splitlines()) == 1
    assert "nope" in err
    assert not (tmp_path / "d").exists()


@pytest.mark.slow
def test_dataset_records_preset_statistics_and_perception(run_cli, tmp_path: Path) -> None:
    out = tmp_path / "mp"
    code, stdout, err = run_cli(
        "sample", "make", "--out", str(out), "--preset", "matterport-like", "--rooms", "1",
        "--frames", "3", "--width", "64", "--height", "48", "--workers", "1",
        "--set", "bias_noise_scale=0.7",
    )  # fmt: skip
    assert code == 0, err
    doc = json.loads((out / "index.json").read_text())
    assert doc["config"]["preset"] == "matterport-like"
    assert doc["config"]["world"]["perception"]["bias_noise_scale"] == 0.7
    stats = doc["statistics"]
    gt = json.loads((out / "scene_000.gt.json").read_text())
    assert stats["rooms"] == 1
    assert stats["instances"] == len(gt["instances"])
    assert stats["classes"] == len({r["class_name"] for r in gt["instances"]})
    assert f"{stats['instances']} instances" in stdout
    assert gt["info"]["perception"]["bias_noise_scale"] == 0.7

    from care_maps.world.perception.model import perception_model, recorded_perception

    record = recorded_perception(out / "scene_000.mcap")
    model, from_record = perception_model("default", record["perception"])
    assert from_record
    assert model.bias_noise_scale == 0.7
    assert model.class_bias_per_scene
    assert record["scene_seed"] == gt["info"]["scene"]["seed"]
    ideal, from_record = perception_model("ideal", record["perception"])
    assert not from_record
    assert ideal.bias_noise_scale == 0.3
    assert ideal.base_noise == 0.0
