"""The CLIP encoder on a real (tiny, randomly initialised) CLIP architecture.

No weights can be downloaded here, so the test builds a small ``CLIPConfig``, saves model,
a BPE tokenizer built from a small vocabulary, and the image processor with
``save_pretrained``, and loads them back through ``make_encoder("clip", weights=DIR)``:
the same path a user takes with a real checkpoint directory.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from care.encoders import EncoderOptions, make_encoder
from care.errors import EncoderError
from care.frames import Frame


def _byte_alphabet() -> list[str]:
    """The printable stand-ins GPT-2 style BPE uses for the 256 byte values."""
    from transformers.convert_slow_tokenizer import bytes_to_unicode

    return list(bytes_to_unicode().values())


@pytest.fixture(scope="module")
def clip_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    import torch
    from transformers import CLIPConfig, CLIPImageProcessor, CLIPModel, CLIPTokenizer

    out = tmp_path_factory.mktemp("tiny-clip")
    chars = _byte_alphabet()
    vocab_list = ["<|startoftext|>", "<|endoftext|>", *chars, *(c + "</w>" for c in chars)]
    vocab = {tok: i for i, tok in enumerate(vocab_list)}
    # A small real BPE: every byte as a token, plus merges for the words of our class names.
    merges = []
    for word in ("chair", "table", "photo"):
        for i in range(1, len(word)):
            left, right = word[:i], word[i] + ("</w>" if i == len(word) - 1 else "")
            merges.append((left, right))
            vocab.setdefault(left + right, len(vocab))
    tokenizer = CLIPTokenizer(vocab=vocab, merges=merges)
    torch.manual_seed(0)
    config = CLIPConfig(
        text_config={
            "vocab_size": len(vocab),
            "hidden_size": 32,
            "intermediate_size": 64,
            "num_hidden_layers": 2,
            "num_attention_heads": 2,
            "max_position_embeddings": 64,
            "eos_token_id": vocab["<|endoftext|>"],
            "bos_token_id": vocab["<|startoftext|>"],
            "pad_token_id": vocab["<|endoftext|>"],
        },
        vision_config={
            "hidden_size": 32,
            "intermediate_size": 64,
            "num_hidden_layers": 2,
            "num_attention_heads": 2,
            "image_size": 32,
            "patch_size": 8,
        },
        projection_dim=16,
    )
    model = CLIPModel(config).eval()
    processor = CLIPImageProcessor(
        size={"shortest_edge": 32}, crop_size={"height": 32, "width": 32}
    )
    model.save_pretrained(out)
    tokenizer.save_pretrained(out)
    processor.save_pretrained(out)
    return out


@pytest.fixture(scope="module")
def encoder(clip_dir: Path):
    return make_encoder("clip", EncoderOptions(weights=str(clip_dir), batch_size=2, device="cpu"))


def _frame(seed: int, shape: tuple[int, int] = (48, 64)) -> Frame:
    rng = np.random.default_rng(seed)
    return Frame(
        stamp_ns=seed,
        rgb=rng.integers(0, 256, (*shape, 3), dtype=np.uint8),
        depth_m=np.ones(shape, np.float32),
        K=np.eye(3),
        cam_to_world=np.eye(4),
    )


def test_dense_maps_have_grid_shape_and_unit_norm(encoder) -> None:
    maps = encoder.encode_views([_frame(i) for i in range(3)])
    fh, fw = encoder.grid_shape(48, 64)
    # short side 48 -> 2 x 32 = 64 px: 8 x 11 patches of 8 px (aspect ratio kept).
    assert (fh, fw) == (8, 11)
    assert maps.shape == (3, fh, fw, 16)
    assert maps.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(maps, axis=-1), 1.0, atol=1e-5)


def test_deterministic_and_batch_invariant(encoder) -> None:
    frames = [_frame(i) for i in range(3)]
    together = encoder.encode_views(frames)
    again = encoder.encode_views(frames)
    np.testing.assert_array_equal(together, again)
    one_by_one = np.concatenate([encoder.encode_views([f]) for f in frames])
    np.testing.assert_allclose(together, one_by_one, atol=1e-5)


def test_dense_features_are_local(encoder) -> None:
    """Changing the left half of an image leaves the right half's patch features nearly as
    they were: the MaskCLIP value path does not mix patches in the last layer."""
    a = _frame(1)
    rgb = a.rgb.copy()
    rgb[:, :32] = 255 - rgb[:, :32]
    b = Frame(a.stamp_ns, rgb, a.depth_m, a.K, a.cam_to_world)
    fa, fb = encoder.encode_views([a, b])
    left = np.sum(fa[:, :3] * fb[:, :3], axis=-1).mean()
    right = np.sum(fa[:, -3:] * fb[:, -3:], axis=-1).mean()
    assert right > left


def test_text_and_crops_share_the_space(encoder) -> None:
    text = encoder.encode_text(["chair", "coffee_table", "tv"])
    crops = encoder.encode_crops([_frame(0).rgb[:20, :30], _frame(1).rgb])
    assert text.shape == (3, 16)
    assert crops.shape == (2, 16)
    np.testing.assert_allclose(np.linalg.norm(text, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(crops, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(encoder.encode_text(["chair"]), text[:1], atol=1e-5)  # padding
    assert not np.allclose(text[0], text[2])
    assert encoder.info(["chair"]).dim == 16


def test_missing_weights_give_one_clear_line(tmp_path: Path) -> None:
    with pytest.raises(EncoderError) as err:
        make_encoder("clip", EncoderOptions(weights=str(tmp_path / "nope")))
    assert "\n" not in str(err.value)
    assert "--weights" in str(err.value)
