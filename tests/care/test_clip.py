"""The CLIP encoder on a small real CLIP (random weights, fixed seed) saved and loaded back.

No weights can be downloaded here, so each test model is built from a real ``CLIPConfig``,
written with ``save_pretrained`` together with a byte-level BPE tokenizer made from a small
vocabulary and a ``CLIPImageProcessor``, and loaded through ``make_encoder("clip", ...)``,
the same path users take with ``--weights DIR`` (the recipe: ``save_tiny_clip`` in
``tests/conftest.py``).
"""

from __future__ import annotations

import json
from pathlib import Path

import huggingface_hub.constants
import numpy as np
import pytest
import torch
import torch.nn.functional as F
from safetensors.torch import load_file

from care_maps.core.encoders import EncoderOptions, make_encoder
from care_maps.core.encoders.clip import ClipEncoder
from care_maps.core.errors import EncoderError
from care_maps.core.frames import Frame

PATCH = 8  # as in save_tiny_clip (tests/conftest.py)
IMAGE = 32
DIM = 16


@pytest.fixture(scope="module")
def clip_dir(tmp_path_factory: pytest.TempPathFactory, save_tiny_clip) -> Path:
    return save_tiny_clip(tmp_path_factory.mktemp("clip") / "tiny-clip", layers=2)


@pytest.fixture(scope="module")
def clip_dir_1layer(tmp_path_factory: pytest.TempPathFactory, save_tiny_clip) -> Path:
    return save_tiny_clip(tmp_path_factory.mktemp("clip") / "tiny-clip-1", layers=1)


@pytest.fixture(scope="module")
def encoder(clip_dir: Path) -> ClipEncoder:
    enc = make_encoder("clip", EncoderOptions(weights=str(clip_dir), batch_size=2))
    assert isinstance(enc, ClipEncoder)
    return enc


def _frame(rgb: np.ndarray, stamp: int = 0) -> Frame:
    h, w = rgb.shape[:2]
    return Frame(stamp, rgb, np.ones((h, w), np.float32), np.eye(3), np.eye(4))


def _random_frames(n: int, h: int = 48, w: int = 64) -> list[Frame]:
    rng = np.random.default_rng(7)
    return [_frame(rng.integers(0, 256, (h, w, 3), dtype=np.uint8), i) for i in range(n)]


@pytest.mark.slow
def test_shapes_normalisation_and_metadata(encoder: ClipEncoder) -> None:
    feats = encoder.encode_views(_random_frames(3))
    # 48 x 64 view, short side scaled to 2 * 32 = 64: 64 x 85.3 px -> 8 x round(10.67) = 11 cells.
    assert feats.shape == (3, 8, 11, DIM)
    assert feats.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(feats, axis=-1), 1.0, atol=1e-5)
    text = encoder.encode_text(["chair", "table", "tv_monitor"])
    assert text.shape == (3, DIM)
    np.testing.assert_allclose(np.linalg.norm(text, axis=-1), 1.0, atol=1e-5)
    crops = encoder.encode_crops([np.zeros((10, 20, 3), np.uint8), np.ones((40, 30, 3), np.uint8)])
    assert crops.shape == (2, DIM)
    np.testing.assert_allclose(np.linalg.norm(crops, axis=-1), 1.0, atol=1e-5)
    assert encoder.dim == DIM
    assert encoder.supports_crops
    assert encoder.version.startswith("tiny-clip+transformers-")
    info = encoder.info(["chair"])
    assert (info.name, info.dim, info.vocabulary) == ("clip", DIM, ("chair",))


def test_deterministic_across_calls_and_loads(encoder: ClipEncoder, clip_dir: Path) -> None:
    frames = _random_frames(2)
    first = encoder.encode_views(frames)
    np.testing.assert_array_equal(first, encoder.encode_views(frames))
    again = make_encoder("clip", EncoderOptions(weights=str(clip_dir), batch_size=2))
    np.testing.assert_array_equal(first, again.encode_views(frames))
    np.testing.assert_array_equal(encoder.encode_text(["chair"]), again.encode_text(["chair"]))


def test_batch_invariance(encoder: ClipEncoder) -> None:
    frames = _random_frames(3)
    batched = encoder.encode_views(frames)  # batch_size 2: one batch of 2, one of 1
    singles = np.concatenate([encoder.encode_views([f]) for f in frames])
    np.testing.assert_allclose(batched, singles, atol=1e-5)
    # Text: padding a short prompt next to a long one must not change its embedding.
    names = ["chair", "a very long class name with many letters"]
    together = encoder.encode_text(names)
    alone = np.concatenate([encoder.encode_text([n]) for n in names])
    np.testing.assert_allclose(together, alone, atol=1e-5)
    crops = [f.rgb for f in frames]
    np.testing.assert_allclose(
        encoder.encode_crops(crops),
        np.concatenate([encoder.encode_crops([c]) for c in crops]),
        atol=1e-5,
    )


def test_constant_image_gives_near_constant_map(encoder: ClipEncoder) -> None:
    def spread(rgb: np.ndarray) -> float:
        cells = encoder.encode_views([_frame(rgb)])[0].reshape(-1, DIM)
        mean = cells.mean(0) / np.linalg.norm(cells.mean(0))
        return float((cells @ mean).min())

    constant = np.full((48, 64, 3), (120, 60, 200), np.uint8)
    noise = np.random.default_rng(1).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    # Only the position embeddings differ between cells of a constant image.
    assert spread(constant) > 0.95
    assert spread(noise) < 0.5


def test_prompt_reads_underscores_as_spaces(encoder: ClipEncoder) -> None:
    a, b, c = encoder.encode_text(["tv_monitor", "tv monitor", "chair"])
    np.testing.assert_allclose(a, b, atol=1e-6)  # same tokens; batch padding differs
    assert float(a @ c) < 0.999


def test_dense_map_matches_maskclip_formula(clip_dir_1layer: Path) -> None:
    """Reference: MaskCLIP's value path written with plain tensor ops on the saved weights.

    A 32 x 32 view at ``short_side=32`` is the model's native input (no resize, no position
    interpolation). For a one-layer ViT the cell of patch p is
    ``proj(ln_post(W_o (W_v ln_1(ln_pre(conv(x)_p + pos_p)) + b_v) + b_o))``.
    """
    enc = ClipEncoder(EncoderOptions(weights=str(clip_dir_1layer)), short_side=IMAGE)
    rgb = np.random.default_rng(3).integers(0, 256, (IMAGE, IMAGE, 3), dtype=np.uint8)
    got = enc.encode_views([_frame(rgb)])[0]
    assert got.shape == (IMAGE // PATCH, IMAGE // PATCH, DIM)

    w = load_file(str(clip_dir_1layer / "model.safetensors"))
    pre = json.loads((clip_dir_1layer / "preprocessor_config.json").read_text())
    mean = torch.tensor(pre["image_mean"]).view(1, 3, 1, 1)
    std = torch.tensor(pre["image_std"]).view(1, 3, 1, 1)
    x = (torch.from_numpy(rgb).permute(2, 0, 1)[None].float() / 255.0 - mean) / std
    v = "vision_model."
    tokens = F.conv2d(x, w[v + "embeddings.patch_embedding.weight"], stride=PATCH)
    tokens = tokens.flatten(2).transpose(1, 2)[0]  # (16, 32), row-major over the grid
    tokens = tokens + w[v + "embeddings.position_embedding.weight"][1:]

    def ln(t: torch.Tensor, name: str) -> torch.Tensor:
        return F.layer_norm(t, (t.shape[-1],), w[name + ".weight"], w[name + ".bias"], 1e-5)

    tokens = ln(tokens, v + "pre_layrnorm")
    layer = v + "encoder.layers.0."
    h = ln(tokens, layer + "layer_norm1")
    h = F.linear(h, w[layer + "self_attn.v_proj.weight"], w[layer + "self_attn.v_proj.bias"])
    h = F.linear(h, w[layer + "self_attn.out_proj.weight"], w[layer + "self_attn.out_proj.bias"])
    h = ln(h, v + "post_layernorm") @ w["visual_projection.weight"].T
    want = F.normalize(h, dim=-1).reshape(IMAGE // PATCH, IMAGE // PATCH, DIM).numpy()
    np.testing.assert_allclose(got, want, atol=1e-5)


def test_last_layer_value_path_is_local(clip_dir_1layer: Path) -> None:
    """With one layer there is no attention mixing: changing pixels (u, v) changes only the
    cell (v * fh // H, u * fw // W), the store's pixel-to-cell rule."""
    enc = ClipEncoder(EncoderOptions(weights=str(clip_dir_1layer)), short_side=32)
    rng = np.random.default_rng(4)
    rgb = rng.integers(0, 256, (32, 48, 3), dtype=np.uint8)  # 4 x 6 cells of 8 px
    changed = rgb.copy()
    changed[8:16, 40:48] = 255 - changed[8:16, 40:48]  # pixels of cell (1, 5)
    a, b = enc.encode_views([_frame(rgb), _frame(changed)])
    diff = np.abs(a - b).max(axis=-1)
    assert diff[1, 5] > 1e-3
    diff[1, 5] = 0
    assert diff.max() < 1e-6


def test_views_of_different_sizes_rejected(encoder: ClipEncoder) -> None:
    frames = [*_random_frames(1), *_random_frames(1, h=32, w=32)]
    with pytest.raises(EncoderError, match=r"views of different sizes"):
        encoder.encode_views(frames)
    with pytest.raises(EncoderError, match=r"crops must be non-empty \(h, w, 3\)"):
        encoder.encode_crops([np.zeros((0, 4, 3), np.uint8)])


def test_missing_weights_directory(tmp_path: Path) -> None:
    with pytest.raises(EncoderError, match=r"--weights .*nothere: no such directory"):
        make_encoder("clip", EncoderOptions(weights=str(tmp_path / "nothere")))
    with pytest.raises(
        EncoderError, match=r"cannot load CLIP from directory .*Pass --weights DIR"
    ) as err:
        make_encoder("clip", EncoderOptions(weights=str(tmp_path)))
    assert "\n" not in str(err.value)


def test_default_checkpoint_offline_says_pass_weights(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(huggingface_hub.constants, "HF_HUB_OFFLINE", True)
    with pytest.raises(
        EncoderError,
        match=r"cannot load CLIP from checkpoint 'openai/clip-vit-base-patch32'.*Pass --weights DIR",
    ):
        make_encoder("clip")
