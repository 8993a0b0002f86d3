"""The perception mechanisms of the ``labels`` encoder, each by itself, on hand-made cases."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from care_maps.core.encoders.base import EncoderOptions
from care_maps.core.errors import EncoderError
from care_maps.world.perception.encoder import LabelsEncoder
from care_maps.world.perception.model import PerceptionModel, perception_model

NAMES = ("void", "wall", "floor", "ceiling", "bed", "pillow", "table", "cup", "chair", "sofa")


def _encoder(model: PerceptionModel, scene_seed: int | None = None) -> LabelsEncoder:
    enc = LabelsEncoder(EncoderOptions(weights="hashed"), model=model)
    enc.scene_seed = scene_seed
    enc.scene_classes = NAMES[4:]
    enc.set_label_names(NAMES)
    return enc


def test_view_bias_reads_the_largest_other_object_of_the_view() -> None:
    model = replace(PerceptionModel.ideal(), view_bias_rate=1.0, view_bias_views=1.0)
    enc = _encoder(model)
    # one view: a pillow (small), the bed (largest), a cup; a second view: the cup alone
    seg_view = np.array([0, 0, 0, 1])
    seg_inst = np.array([1, 2, 3, 3])
    seg_cls = np.array([5, 4, 7, 7])
    area = np.array([50, 900, 20, 400])
    stamp = np.array([10, 10, 10, 20], np.uint64)
    got = enc._view_bias(seg_view, seg_inst, seg_cls, stamp, area, seg_cls.copy())
    # pillow and cup read as the bed; the bed as the next largest (the pillow); the cup
    # alone in its view has no context: its nearest class by text
    assert got.tolist() == [4, 5, 4, int(enc.nearest[7])]
    off = _encoder(replace(model, view_bias_rate=0.0))
    assert off._view_bias(seg_view, seg_inst, seg_cls, stamp, area, seg_cls).tolist() == [
        5,
        4,
        7,
        7,
    ]


def test_view_bias_misreads_the_chosen_fraction_of_views() -> None:
    model = replace(PerceptionModel.ideal(), view_bias_rate=1.0, view_bias_views=0.3)
    enc = _encoder(replace(model, view_bias_context=False))
    n = 4000
    stamps = np.arange(n, dtype=np.uint64)
    got = enc._view_bias(
        np.arange(n), np.full(n, 7), np.full(n, 5), stamps, np.full(n, 10), np.full(n, 5)
    )
    assert abs(np.mean(got != 5) - 0.3) < 0.03  # binomial sd 0.007


def test_class_bias_is_drawn_per_scene_when_asked() -> None:
    model = replace(PerceptionModel.ideal(), class_bias_rate=0.5)
    per_seed = [_encoder(model, s).class_biased.copy() for s in range(6)]
    assert all(np.array_equal(per_seed[0], b) for b in per_seed)  # once per encoder seed
    scene = replace(model, class_bias_per_scene=True)
    per_scene = [_encoder(scene, s).class_biased.copy() for s in range(6)]
    assert len({b.tobytes() for b in per_scene}) > 1
    assert all(b.sum() == 3 for b in per_scene)  # half of the scene's 6 classes
    assert not any(b[:4].any() for b in per_scene)  # never the room's shell


def test_perception_spec_overrides_and_errors() -> None:
    model, from_record = perception_model("default:view_bias_rate=0.2,class_bias_per_scene=on")
    assert model.view_bias_rate == 0.2
    assert model.class_bias_per_scene
    assert not from_record
    recorded, from_record = perception_model("default:base_noise=0.1", {"bias_noise_scale": 1})
    assert from_record
    assert recorded.bias_noise_scale == 1.0
    assert recorded.base_noise == 0.1
    for bad in ("nope", "default:x=1", "default:base_noise=-1", "default:base_noise"):
        with pytest.raises(EncoderError):
            perception_model(bad)
