"""The timing checkpoints' tokenizer (:mod:`care_maps.core.encoders.random_clip`): each word
of the bundled vocabularies' prompts is one token, as in CLIP's own vocabulary, so the text
tower's cost in the benchmarks is a real checkpoint's; a word it never saw still tokenizes."""

from __future__ import annotations

import re
from pathlib import Path

from care_maps.core.encoders.clip import PROMPT_TEMPLATE
from care_maps.core.encoders.random_clip import _learnt_merges, _tokenizer_files
from care_maps.core.vocab import load_vocabulary

PIECES = re.compile(r"[a-z]+|[0-9]|[^\sa-z0-9]+")
"""CLIP's pre-tokenising pattern for lower-case ASCII text (letters, a digit, other symbols)."""


def _tokenizer(out: Path):
    from transformers import CLIPTokenizer

    vocab = _tokenizer_files(out)
    files = {"vocab": str(out / "vocab.json"), "merges": str(out / "merges.txt")}
    _learnt_merges(out, vocab, CLIPTokenizer(**files))
    return CLIPTokenizer(**files)


def test_each_word_of_a_bundled_prompt_is_one_token(tmp_path: Path) -> None:
    tokenizer = _tokenizer(tmp_path)
    prompts = [PROMPT_TEMPLATE.format(n.replace("_", " ")) for n in load_vocabulary("scannet200")]
    for prompt in prompts:
        ids = tokenizer(prompt)["input_ids"]
        assert len(ids) == 2 + len(PIECES.findall(prompt.lower())), prompt  # start and end
    tokens = tokenizer.convert_ids_to_tokens(tokenizer("a photo of a coffee table.")["input_ids"])
    assert tokens[1:-1] == ["a</w>", "photo</w>", "of</w>", "a</w>", "coffee</w>", "table</w>",
                            ".</w>"]  # fmt: skip
    unseen = tokenizer("a photo of a zebra.")["input_ids"]
    assert len(unseen) > 2 + len(PIECES.findall("a photo of a zebra."))
    # CLIP's decoding: every end of word a space, the full stop one too
    assert tokenizer.decode(unseen, skip_special_tokens=True).strip() == "a photo of a zebra ."
