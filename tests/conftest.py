"""Fixtures shared by every test package."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

TINY_CLIP_PATCH = 8
TINY_CLIP_IMAGE = 32
TINY_CLIP_DIM = 16

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Third-party test data handed to the project (read-only), see ../shared/data/README.md."""
    path = SHARED / "data"
    if not path.is_dir():
        pytest.skip(f"{path} not present")
    return path


def _save_tiny_clip(out: Path, layers: int) -> Path:
    """A real CLIP (random weights, seed 0) written with ``save_pretrained``: model, a real
    byte-level BPE tokenizer over a small vocabulary, and an image processor."""
    from transformers import CLIPConfig, CLIPImageProcessor, CLIPModel, CLIPTokenizer

    out.mkdir(parents=True)
    from transformers.convert_slow_tokenizer import bytes_to_unicode

    # A real byte-level BPE: one token per byte symbol (with and without the end-of-word
    # mark), plus merges for "chair", so any text tokenizes.
    vocab = {"<|startoftext|>": 0, "<|endoftext|>": 1}
    for c in bytes_to_unicode().values():
        vocab[c] = len(vocab)
        vocab[c + "</w>"] = len(vocab)
    merges = ["c h", "ch a", "cha i", "chai r</w>"]
    for token in ("ch", "cha", "chai", "chair</w>"):
        vocab[token] = len(vocab)
    (out / "vocab.json").write_text(json.dumps(vocab))
    (out / "merges.txt").write_text("#version: 0.2\n" + "\n".join(merges) + "\n")
    tokenizer = CLIPTokenizer(vocab=str(out / "vocab.json"), merges=str(out / "merges.txt"))
    import torch

    torch.manual_seed(0)
    config = CLIPConfig(
        text_config={
            "vocab_size": len(vocab),
            "hidden_size": 32,
            "intermediate_size": 64,
            "num_hidden_layers": 2,
            "num_attention_heads": 4,
            "max_position_embeddings": 32,
            "bos_token_id": 0,
            "eos_token_id": 1,
            "pad_token_id": 1,
        },
        vision_config={
            "hidden_size": 32,
            "intermediate_size": 64,
            "num_hidden_layers": layers,
            "num_attention_heads": 4,
            "image_size": TINY_CLIP_IMAGE,
            "patch_size": TINY_CLIP_PATCH,
        },
        projection_dim=TINY_CLIP_DIM,
    )
    CLIPModel(config).save_pretrained(out)
    tokenizer.save_pretrained(out)
    CLIPImageProcessor(
        size={"shortest_edge": TINY_CLIP_IMAGE},
        crop_size={"height": TINY_CLIP_IMAGE, "width": TINY_CLIP_IMAGE},
    ).save_pretrained(out)
    return out


@pytest.fixture(scope="session")
def save_tiny_clip():
    """``save_tiny_clip(out_dir, layers)``: write a tiny real CLIP checkpoint, return its path."""
    return _save_tiny_clip


@pytest.fixture
def run_cli(capsys: pytest.CaptureFixture[str]) -> Callable[..., tuple[int, str, str]]:
    """Run ``care ARGS`` in-process through ``care_cli.main.main``: (exit code, stdout, stderr)."""
    from care_cli import main as cli

    def run(*args: str) -> tuple[int, str, str]:
        argv = sys.argv
        sys.argv = ["care", *map(str, args)]
        code = 0
        try:
            cli.main()
        except SystemExit as exc:
            code = int(exc.code or 0)
        finally:
            sys.argv = argv
        out, err = capsys.readouterr()
        return code, out, err

    return run
