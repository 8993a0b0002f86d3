"""The CLIP-like similarity model: its measured statistics fall in the published target
ranges, its gap direction is orthogonal to every class text, its confusions follow text
similarity, and the direct model (every preset before it) encodes exactly as before."""

from __future__ import annotations

import hashlib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from care_maps.core.encoders import EncoderOptions
from care_maps.core.frames import Frame
from care_maps.world.perception.encoder import LabelsEncoder
from care_maps.world.perception.model import PerceptionModel
from care_maps.world.presets import PRESETS, WorldPreset

NAMES = (
    "void", "wall", "floor", "table", "chair", "sofa", "bed", "tv", "lamp", "plant", "toilet",
    "sink", "cabinet", "desk", "coffee table", "monitor", "bookshelf", "shelf", "vase", "bowl",
)  # fmt: skip
H, W = 120, 160
K = np.array([[100.0, 0, 80], [0, 100.0, 60], [0, 0, 1]])

DIRECT_DIGESTS = {
    "default": "66923e0f67a70a33d7932613af725810d5c3c16bb84bd45a8214eebe9d9971db",
    "matterport-like": "1fd25180763c4366509361257186951cddf9a0c459d73f1c518d8d9ceece7ded",
}
"""SHA-256 of the rounded features of :func:`_views` under each preset's perception model,
computed with the encoder as it was before the CLIP-like model existed."""


def _views(n_views: int = 4) -> list[Frame]:
    """Views of a wall with a 4 x 3 grid of objects (instances 1..12, classes 3..14) that
    shift and recede from view to view."""
    frames = []
    for j in range(n_views):
        inst = np.zeros((H, W), np.uint16)
        cls = np.ones((H, W), np.uint16)
        for k in range(12):
            r, c = divmod(k, 4)
            v0, u0 = 6 + 38 * r + (3 * j) % 6, 4 + 40 * c + 3 * j
            inst[v0 : v0 + 28, u0 : u0 + 30] = k + 1
            cls[v0 : v0 + 28, u0 : u0 + 30] = 3 + k
        frames.append(
            Frame(
                stamp_ns=1_000_000_000 + j * 100_000_000,
                rgb=np.zeros((H, W, 3), np.uint8),
                depth_m=np.full((H, W), 2.0 + j, np.float32),
                K=K,
                cam_to_world=np.eye(4),
                extras={"instance": inst, "class": cls},
            )
        )
    return frames


def direct_digest(model: PerceptionModel) -> str:
    """Digest of the (hashed-text) features of :func:`_views` under ``model``."""
    enc = LabelsEncoder(EncoderOptions(seed=0, weights="hashed"), model=model)
    enc.set_label_names(NAMES)
    feats = enc.encode_views(_views())
    return hashlib.sha256(np.round(feats, 5).astype(np.float32).tobytes()).hexdigest()


def _minilm() -> None:
    from care_maps.core.encoders.sentence import SentenceBackend, sentence_model

    if sentence_model(SentenceBackend.AUTO).backend != SentenceBackend.MINILM:
        pytest.skip("all-MiniLM-L6-v2 is not installed: the CLIP-like model is set for it")


# -- the direct model is unchanged ------------------------------------------------------------


@pytest.mark.parametrize("preset", ["default", "matterport-like"])
def test_direct_model_encodes_as_before(preset: str) -> None:
    model = PRESETS[WorldPreset(preset)].perception
    assert direct_digest(model) == DIRECT_DIGESTS[preset]


def test_clip_knobs_do_not_touch_the_direct_model() -> None:
    from care_maps.world.perception.model import SimilarityModel

    model = PRESETS[WorldPreset.MATTERPORT_LIKE].perception
    assert model.similarity_model is SimilarityModel.DIRECT
    other = replace(model, clip_text_weight=0.9, clip_noise=0.0, clip_gap_weight=0.1)
    assert direct_digest(other) == direct_digest(model)


def test_matterport_clip_is_matterport_like_with_clip_like_similarities() -> None:
    from care_maps.world.perception.model import CLIP_LIKE_KNOBS, SimilarityModel

    like, clip = PRESETS[WorldPreset.MATTERPORT_LIKE], PRESETS[WorldPreset.MATTERPORT_CLIP]
    assert clip.perception.similarity_model is SimilarityModel.CLIP_LIKE
    assert replace(clip.perception, similarity_model=SimilarityModel.DIRECT) == like.perception
    assert clip.scene_values() == like.scene_values()
    # a direct dataset records no knob of the CLIP-like model (its bytes are as before)
    assert not set(CLIP_LIKE_KNOBS) & set(like.as_json()["perception"])
    recorded = clip.as_json()["perception"]
    assert recorded["similarity_model"] == "clip_like"
    assert PerceptionModel().with_values(recorded) == clip.perception


def test_similarity_model_knob_parses_and_refuses_unknown_names() -> None:
    from care_maps.core.errors import WorldError
    from care_maps.world.perception.model import SimilarityModel
    from care_maps.world.presets import with_sets

    out = with_sets(PRESETS[WorldPreset.DEFAULT], ["similarity_model=clip_like"])
    assert out.perception.similarity_model is SimilarityModel.CLIP_LIKE
    with pytest.raises(WorldError, match="similarity_model"):
        with_sets(PRESETS[WorldPreset.DEFAULT], ["similarity_model=siglip"])


# -- geometry -------------------------------------------------------------------------------


def _clip_encoder(weights: str | None = None) -> LabelsEncoder:
    model = PRESETS[WorldPreset.MATTERPORT_CLIP].perception
    enc = LabelsEncoder(EncoderOptions(seed=3, weights=weights), model=model)
    enc.set_label_names(NAMES)
    return enc


@pytest.mark.parametrize("weights", ["hashed", None])
def test_gap_direction_is_a_unit_vector_orthogonal_to_every_class_text(weights) -> None:
    enc = _clip_encoder(weights)
    assert np.linalg.norm(enc.gap) == pytest.approx(1.0)
    assert np.abs(enc.text @ enc.gap).max() < 1e-6
    # fixed per encoder seed, other seeds another direction
    assert np.allclose(_clip_encoder(weights).gap, enc.gap)
    other = LabelsEncoder(EncoderOptions(seed=4, weights=weights), model=enc.model)
    other.set_label_names(NAMES)
    assert abs(float(other.gap @ enc.gap)) < 0.5


def test_clip_like_segment_features_sit_far_from_the_texts() -> None:
    enc = _clip_encoder("hashed")
    feats = enc.encode_views(_views())
    assert np.allclose(np.linalg.norm(feats, axis=-1), 1.0, atol=1e-5)
    cos = feats.reshape(-1, feats.shape[-1]) @ enc.text.T
    assert cos.max() < 0.6  # nowhere near the direct model's 0.97


# -- measured against the targets ----------------------------------------------------------


@pytest.fixture(scope="module")
def clip_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small matterport-clip recording (two rooms, 24 views of 160 x 120)."""
    from care_maps.world.record import make_recording
    from care_maps.world.render import RenderConfig
    from care_maps.world.scene import SceneConfig

    world = PRESETS[WorldPreset.MATTERPORT_CLIP]
    path = tmp_path_factory.mktemp("clip") / "scene.mcap"
    make_recording(
        path,
        SceneConfig(seed=3, num_rooms=2, **world.scene_values()),
        RenderConfig(width=160, height=120),
        frames=24,
        perception=world.as_json()["perception"],
    )
    return path


def test_matterport_clip_statistics_fall_in_the_target_ranges(clip_recording: Path) -> None:
    from care_maps.world.perception.likeness import (
        TARGETS,
        likeness_table,
        measure_recording,
        off_target,
    )

    _minilm()
    measured = measure_recording(clip_recording, views=24)
    assert measured["object_views"] >= 40
    assert off_target(measured) == [], likeness_table(measured, markdown=False)
    assert {t.name for t in TARGETS} <= set(measured)


def test_the_direct_model_misses_them_as_the_review_found(clip_recording: Path) -> None:
    from care_maps.world.perception.likeness import measure_recording, off_target

    _minilm()
    direct = measure_recording(
        clip_recording, views=24, perception="default:similarity_model=direct"
    )
    assert direct["top_prob_over_0999"] > 0.5  # most views one-hot at logit scale 100
    assert direct["best_cosine"] > 0.9
    assert {"best_cosine", "margin", "top_prob_over_0999"} <= set(off_target(direct))


def test_confusions_follow_text_similarity(clip_recording: Path) -> None:
    """Independent of likeness.py: per view and object, the cosines to the wrong object
    classes rank like their text similarities to the true class (scipy's spearmanr)."""
    from scipy.stats import spearmanr

    from care_maps.core.encoders import RecordingContext, make_encoder
    from care_maps.core.vocab import STRUCTURE_NAMES
    from care_maps.ingest.source import RecordingFrames

    _minilm()
    with RecordingFrames(clip_recording) as reader:
        frames = list(reader)[::3]
        names = reader.label_names
    enc = make_encoder("labels", EncoderOptions(seed=0))
    enc.prepare(RecordingContext(source=clip_recording, label_names=names))
    feats = enc.encode_views(frames)
    text = enc.encode_text(names)
    objects = np.array([n.lower() not in STRUCTURE_NAMES for n in names])
    rhos = []
    for view, frame in zip(feats, frames, strict=True):
        inst, cls = frame.extras["instance"], frame.extras["class"]
        fh, fw = view.shape[:2]
        v, u = np.mgrid[0 : frame.height, 0 : frame.width]
        cell_feat = view[v * fh // frame.height, u * fw // frame.width]
        for i in np.unique(inst[inst > 0]):
            mask = inst == i
            y = int(np.bincount(cls[mask]).argmax())
            if mask.sum() < 20 or not objects[y]:
                continue
            f = cell_feat[mask].mean(0)
            wrong = objects.copy()
            wrong[y] = False
            rho = spearmanr(text[wrong] @ f, text[wrong] @ text[y]).statistic
            rhos.append(rho)
    assert len(rhos) >= 30
    assert np.median(rhos) > 0.2
    assert np.mean(np.asarray(rhos) > 0) > 0.8
