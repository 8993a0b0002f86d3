"""A CLIP checkpoint with random weights, written with ``save_pretrained``: what tests and
benchmarks load where no real weights can be downloaded.

The files are those of a real checkpoint (the model, a byte-level BPE tokenizer, an image
processor), so every loading path of :mod:`care_maps.core.encoders.clip` runs as on ``openai/clip-*``;
only the weights (seed 0) and the tokenizer's vocabulary (one token per byte symbol, with and
without the end-of-word mark, plus merges) are made up. Three sizes: a tiny one for tests
(merges for "chair" alone), and ViT-B/32's and ViT-L/14's architectures for timing and memory,
whose merges are learnt by ``tokenizers``' BPE trainer from the bundled vocabularies' prompts:
each of their words is one token, as a common English word is in CLIP's 49,152 merges, so a
prompt costs the text tower the tokens it costs on a real checkpoint (ScanNet200's: 8.4 a
prompt, where one token a letter made 20.2).
"""

from __future__ import annotations

import json
from enum import StrEnum
from pathlib import Path
from typing import Any

__all__ = ["TINY_DIM", "TINY_IMAGE", "TINY_PATCH", "ClipSize", "save_random_clip"]

TINY_PATCH = 8
TINY_IMAGE = 32
TINY_DIM = 16


class ClipSize(StrEnum):
    """The architecture of a random checkpoint."""

    TINY = "tiny"
    """32-wide towers, 2 text layers: a test loads and runs it in milliseconds."""
    VIT_B32 = "vit-b32"
    """ViT-B/32's towers and projection: its load time and memory are a real checkpoint's."""
    VIT_L14 = "vit-l14"
    """ViT-L/14's (``openai/clip-vit-large-patch14``): 24 vision layers of width 1024, patch
    14, a 768-wide text tower and projection."""


_VIT_L14_TEXT = {
    "hidden_size": 768,
    "intermediate_size": 3072,
    "num_attention_heads": 12,
    "num_hidden_layers": 12,
}
_VIT_L14_VISION = {
    "hidden_size": 1024,
    "intermediate_size": 4096,
    "num_attention_heads": 16,
    "num_hidden_layers": 24,
    "image_size": 224,
    "patch_size": 14,
}
"""ViT-L/14's towers, from the checkpoint's ``config.json`` (the rest: ``CLIPConfig``'s defaults)."""


def _tokenizer_files(out: Path) -> dict[str, int]:
    from transformers.convert_slow_tokenizer import bytes_to_unicode

    vocab = {"<|startoftext|>": 0, "<|endoftext|>": 1}
    for c in bytes_to_unicode().values():
        vocab[c] = len(vocab)
        vocab[c + "</w>"] = len(vocab)
    merges = ["c h", "ch a", "cha i", "chai r</w>"]
    for token in ("ch", "cha", "chai", "chair</w>"):
        vocab[token] = len(vocab)
    (out / "vocab.json").write_text(json.dumps(vocab))
    (out / "merges.txt").write_text("#version: 0.2\n" + "\n".join(merges) + "\n")
    return vocab


def _learnt_merges(out: Path, vocab: dict[str, int], tokenizer: Any) -> dict[str, int]:
    """Rewrite ``out``'s vocabulary and merges with BPE merges learnt from the bundled
    vocabularies' prompts (CLIP's normaliser and pre-tokeniser, ``</w>`` ending a word; every
    merge the prompts allow, so each of their words ends as one token)."""
    from tokenizers import Tokenizer, models, pre_tokenizers, trainers

    from care_maps.core.encoders.clip import PROMPT_TEMPLATE
    from care_maps.core.vocab import bundled_vocabularies, load_vocabulary

    backend = tokenizer.backend_tokenizer
    learner = Tokenizer(models.BPE(end_of_word_suffix="</w>"))
    learner.normalizer = backend.normalizer
    learner.pre_tokenizer = backend.pre_tokenizer
    trainer = trainers.BpeTrainer(
        vocab_size=1 << 20,  # no limit: merging goes on while a pair is left
        special_tokens=["<|startoftext|>", "<|endoftext|>"],
        initial_alphabet=pre_tokenizers.ByteLevel.alphabet(),
        end_of_word_suffix="</w>",
        show_progress=False,
    )
    prompts = [
        PROMPT_TEMPLATE.format(name.replace("_", " ").strip())
        for bundled in bundled_vocabularies()
        for name in load_vocabulary(bundled)
    ]
    learner.train_from_iterator(prompts, trainer)
    learnt = json.loads(learner.to_str())["model"]["merges"]
    merges = [pair if isinstance(pair, str) else " ".join(pair) for pair in learnt]
    vocab = dict(vocab)
    for merge in merges:
        vocab.setdefault(merge.replace(" ", ""), len(vocab))
    (out / "vocab.json").write_text(json.dumps(vocab))
    (out / "merges.txt").write_text("#version: 0.2\n" + "\n".join(merges) + "\n")
    return vocab


def save_random_clip(out: Path, *, size: ClipSize = ClipSize.TINY, layers: int = 2) -> Path:
    """Write a random CLIP of ``size`` to the new directory ``out`` and return it
    (``layers``: the tiny vision tower's depth)."""
    import torch
    from transformers import CLIPConfig, CLIPImageProcessor, CLIPModel, CLIPTokenizer

    out = Path(out)
    out.mkdir(parents=True)
    vocab = _tokenizer_files(out)
    tokenizer = CLIPTokenizer(vocab=str(out / "vocab.json"), merges=str(out / "merges.txt"))
    if size is not ClipSize.TINY:
        vocab = _learnt_merges(out, vocab, tokenizer)
        tokenizer = CLIPTokenizer(vocab=str(out / "vocab.json"), merges=str(out / "merges.txt"))
    ids = {"vocab_size": len(vocab), "bos_token_id": 0, "eos_token_id": 1, "pad_token_id": 1}
    torch.manual_seed(0)
    if size is ClipSize.TINY:
        config = CLIPConfig(
            text_config={
                **ids,
                "hidden_size": 32,
                "intermediate_size": 64,
                "num_hidden_layers": 2,
                "num_attention_heads": 4,
                "max_position_embeddings": 32,
            },
            vision_config={
                "hidden_size": 32,
                "intermediate_size": 64,
                "num_hidden_layers": layers,
                "num_attention_heads": 4,
                "image_size": TINY_IMAGE,
                "patch_size": TINY_PATCH,
            },
            projection_dim=TINY_DIM,
        )
        processor = CLIPImageProcessor(
            size={"shortest_edge": TINY_IMAGE},
            crop_size={"height": TINY_IMAGE, "width": TINY_IMAGE},
        )
    elif size is ClipSize.VIT_L14:
        config = CLIPConfig(
            text_config={**ids, **_VIT_L14_TEXT},
            vision_config=_VIT_L14_VISION,
            projection_dim=768,
        )
        processor = CLIPImageProcessor()
    else:
        config = CLIPConfig(text_config=ids)
        processor = CLIPImageProcessor()
    CLIPModel(config).save_pretrained(out)
    tokenizer.save_pretrained(out)
    processor.save_pretrained(out)
    return out
